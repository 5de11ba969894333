"""Per-camera intrinsics: view selection, cv2.calibrateCameraExtended, cross-validation.

View selection is greedy over the usable views: each pick maximises new image coverage
(cells of a grid over the image that get their first corner), new board tilts (bins of
tilt magnitude and direction relative to the line of sight), sharpness (a still board)
and size, so a few dozen views constrain the lens as well as hundreds would.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from mamma_kit.calibration.board import BoardSpec
from mamma_kit.calibration.detect import Detections
from mamma_kit.calibration.lens import undistort_exact
from mamma_kit.core.camera import Camera, rodrigues
from mamma_kit.core.errors import UserError
from mamma_kit.core.lens import LENSES, coefficient_names, distort_normalized, require_solvable
from mamma_kit.core import log

K_NAMES = ["fx", "fy", "cx", "cy"]  # the intrinsics before the lens coefficients, in OpenCV's order


@dataclass
class IntrinsicResult:
    camera: Camera  # R = I, t = 0
    rms_px: float
    views: np.ndarray  # frame indices (into the Detections) used
    per_view_rms: np.ndarray  # (V,)
    rvecs: np.ndarray  # (V, 3) board -> camera
    tvecs: np.ndarray  # (V, 3)
    std: dict = field(default_factory=dict)  # 1-sigma of fx, fy, cx, cy, distortion
    coverage: float = 0.0  # fraction of image grid cells with a corner
    max_tilt_deg: float = 0.0
    fixed: bool = False
    removed_corners: int = 0


# ---- pose helpers -------------------------------------------------------------------------
def undistort_points(cam: Camera, xy_n2: np.ndarray) -> np.ndarray:
    """Pixels -> undistorted normalised coordinates (vectorised, exact)."""
    return undistort_exact(cam, xy_n2)


def board_pose(cam: Camera, spec: BoardSpec, xy_n2: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Board -> camera (rvec, tvec) from one view's corners (NaN rows ignored), and the
    view's reprojection RMS (px). Planar IPPE on undistorted points, then LM refinement."""
    ok = np.isfinite(xy_n2[:, 0])
    if ok.sum() < 4:
        return None
    obj = spec.corners_b3[ok]
    xn = undistort_points(cam, xy_n2[ok])
    try:
        good, rvec, tvec = cv2.solvePnP(obj, xn.reshape(-1, 1, 2), np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
    except cv2.error:
        return None
    if not good:
        return None
    rvec, tvec = cv2.solvePnPRefineLM(obj, xn.reshape(-1, 1, 2), np.eye(3), None, rvec, tvec)
    rvec, tvec = rvec.ravel(), tvec.ravel()
    if tvec[2] <= 0:
        return None
    X = obj @ rodrigues(rvec).T + tvec
    proj = cam.normalized_to_pixels(distort_normalized(X[:, :2] / X[:, 2:], cam.model, cam.dist))
    rms = float(np.sqrt(np.mean(np.sum((proj - xy_n2[ok]) ** 2, 1))))
    return rvec, tvec, rms


def tilt_of(rvec: np.ndarray, tvec: np.ndarray, spec: BoardSpec) -> tuple[float, float]:
    """(tilt angle between the board normal and the line of sight (deg), tilt direction (rad))."""
    R = rodrigues(rvec)
    c = R @ spec.center_b3 + tvec
    los = c / np.linalg.norm(c)
    n = R[:, 2]  # into the board, i.e. away from the camera for a visible board
    ang = np.degrees(np.arccos(np.clip(abs(n @ los), -1, 1)))
    # direction of the tilt in the image plane
    d = n - (n @ los) * los
    return float(ang), float(np.arctan2(d[1], d[0]))


# ---- calibration --------------------------------------------------------------------------
def _flags(model: str) -> int:
    if model == "rational":
        return cv2.CALIB_RATIONAL_MODEL
    return 0


def _calibrate(model: str, obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int],
               K0: np.ndarray | None = None, d0: np.ndarray | None = None, extra_flags: int = 0):
    """-> (rms, K, dist, rvecs, tvecs, std (dict) or None, per-view errors)."""
    w, h = size
    if model == "fisheye":
        K = K0.copy() if K0 is not None else np.array([[max(w, h) * 0.8, 0, (w - 1) / 2],
                                                        [0, max(w, h) * 0.8, (h - 1) / 2], [0, 0, 1.0]])
        D = (d0.copy() if d0 is not None else np.zeros(4)).reshape(4, 1)
        # (OpenCV 5: the general CALIB_* flags, and points shaped (1, N, 3) / (1, N, 2))
        flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW
        if K0 is not None:
            flags |= cv2.CALIB_USE_INTRINSIC_GUESS
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
        o = [x.reshape(1, -1, 3).astype(np.float64) for x in obj]
        i = [x.reshape(1, -1, 2).astype(np.float64) for x in img]
        rms, K, D, rv, tv = cv2.fisheye.calibrate(o, i, (w, h), K, D, flags=flags, criteria=crit)
        rv = np.array([np.ravel(r) for r in rv])
        tv = np.array([np.ravel(t) for t in tv])
        cam = Camera("c", size, K, D.ravel(), "fisheye")
        errs = np.array([_view_rms(cam, o_.reshape(-1, 3), i_.reshape(-1, 2), r, t) for o_, i_, r, t in zip(o, i, rv, tv)])
        return rms, K, D.ravel(), rv, tv, None, errs
    flags = _flags(model) | extra_flags
    if K0 is not None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    K = K0.copy() if K0 is not None else None
    D = None
    if d0 is not None:
        D = np.zeros(14)
        D[:len(d0)] = d0
    o = [x.astype(np.float32) for x in obj]
    i = [x.astype(np.float32) for x in img]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, K, D, rv, tv, std_i, _std_e, errs = cv2.calibrateCameraExtended(o, i, (w, h), K, D, flags=flags,
                                                                        criteria=crit)
    nd = LENSES[model].solve_coeffs
    std_i = std_i.ravel()
    # OpenCV's stdDeviationsIntrinsics: fx, fy, cx, cy, then the coefficients in the table's order
    std = {n: float(v) for n, v in zip(K_NAMES + coefficient_names(model, nd), std_i[:4 + nd])}
    return rms, K, D.ravel()[:nd], np.array([np.ravel(r) for r in rv]), np.array([np.ravel(t) for t in tv]), \
        std, np.asarray(errs).ravel()


def _cv_reason(e: Exception) -> str:
    """The human part of an OpenCV error message."""
    text = str(e)
    if ") " in text and "error: (" in text:
        text = text.split("error: (", 1)[1]
        text = text.split(") ", 1)[1] if ") " in text else text
    return " ".join(text.split())[:120]


def _view_rms(cam: Camera, obj: np.ndarray, img: np.ndarray, rvec, tvec) -> float:
    X = obj @ rodrigues(rvec).T + tvec
    p = cam.normalized_to_pixels(distort_normalized(X[:, :2] / X[:, 2:], cam.model, cam.dist))
    return float(np.sqrt(np.mean(np.sum((p - img) ** 2, 1))))


def _residuals(cam: Camera, obj: np.ndarray, img: np.ndarray, rvec, tvec) -> np.ndarray:
    X = obj @ rodrigues(rvec).T + tvec
    return cam.normalized_to_pixels(distort_normalized(X[:, :2] / X[:, 2:], cam.model, cam.dist)) - img


def _grid_cells(xy_n2: np.ndarray, size: tuple[int, int], nx: int = 10) -> np.ndarray:
    """Ids of the image grid cells (about nx across, square cells) holding the points."""
    w, h = size
    ny = max(2, round(nx * h / w))
    cx = np.clip((xy_n2[:, 0] / w * nx).astype(int), 0, nx - 1)
    cy = np.clip((xy_n2[:, 1] / h * ny).astype(int), 0, ny - 1)
    return np.unique(cy * nx + cx)


def select_views(det: Detections, spec: BoardSpec, cam0: Camera, frames: np.ndarray, max_views: int,
                 exclude_near: float = 0.15) -> tuple[np.ndarray, dict]:
    """Greedy choice of views for intrinsics (see the module docstring)."""
    w, h = det.size
    nx = 10
    ny = max(2, round(nx * h / w))
    cells, tiltbins, size_frac, sharp, ok = [], [], [], [], []
    xy = det.xy_fn2
    # stillness: corner motion to the neighbouring sampled frames (px)
    def motion(i, j):
        if j < 0 or j >= len(xy):
            return np.nan
        m = np.isfinite(xy[i, :, 0]) & np.isfinite(xy[j, :, 0])
        return float(np.max(np.linalg.norm(xy[i, m] - xy[j, m], axis=1))) if m.sum() >= 3 else np.nan
    info = {}
    for f in frames:
        pose = board_pose(cam0, spec, xy[f])
        if pose is None:
            ok.append(False)
            cells.append(np.array([], int))
            tiltbins.append(-1)
            size_frac.append(0.0)
            sharp.append(0.0)
            continue
        rvec, tvec, rms = pose
        pts = xy[f][np.isfinite(xy[f, :, 0])]
        cells.append(_grid_cells(pts, det.size, nx))
        tilt, direction = tilt_of(rvec, tvec, spec)
        mag_bin = int(np.digitize(tilt, [10, 22, 35, 50]))
        dir_bin = int(((direction + np.pi) / (2 * np.pi) * 8)) % 8 if mag_bin > 0 else 0
        tiltbins.append(mag_bin * 8 + dir_bin)
        span = np.ptp(pts, axis=0)
        size_frac.append(float(span[0] * span[1] / (w * h)))
        mv = np.nanmax([motion(f, f - 1), motion(f, f + 1), 0.0])
        sharp.append(float(np.exp(-mv / 3.0)))  # ~1 for a still board, small when it moves fast
        ok.append(rms < 5.0)
        info[int(f)] = {"tilt_deg": tilt, "rms0": rms}
    ok = np.array(ok)
    chosen: list[int] = []
    covered: set[int] = set()
    tilts_seen: set[int] = set()
    times = det.times_f
    n_corner = det.n_corners_f
    cand = [k for k in range(len(frames)) if ok[k]]
    while cand and len(chosen) < max_views:
        best, best_score = None, -np.inf
        for k in cand:
            new_cells = len(set(cells[k].tolist()) - covered)
            score = (3.0 * new_cells / (nx * ny) * 10 + (2.0 if tiltbins[k] not in tilts_seen else 0.0)
                     + 0.02 * n_corner[frames[k]] / spec.n_corners * 10 + 1.5 * np.sqrt(size_frac[k])
                     + 2.0 * sharp[k])
            if chosen and np.min(np.abs(times[frames[chosen]] - times[frames[k]])) < exclude_near:
                score -= 5.0  # near-duplicate of a chosen frame
            if score > best_score:
                best, best_score = k, score
        chosen.append(best)
        covered |= set(cells[best].tolist())
        tilts_seen.add(tiltbins[best])
        cand.remove(best)
    sel = np.sort(frames[chosen])
    all_cells = set()
    for k in range(len(frames)):
        if ok[k]:
            all_cells |= set(cells[k].tolist())
    return sel, {"coverage": len(covered) / (nx * ny), "coverage_all": len(all_cells) / (nx * ny),
                 "tilts": {int(f): info[int(f)]["tilt_deg"] for f in sel}}


def _plausible(K: np.ndarray, size: tuple[int, int]) -> bool:
    """Square-ish pixels, a focal length of a real lens and the principal point in the image:
    LM can wander off to a far minimum (fy 30x fx) when the views constrain focal length weakly."""
    w, h = size
    fx, fy = K[0, 0], K[1, 1]
    return bool(0 <= K[0, 2] < w and 0 <= K[1, 2] < h and fx > 0 and fy > 0 and 0.8 < fx / fy < 1.25
                and 0.15 * max(w, h) < fx < 20 * max(w, h))


def _initial_intrinsics(obj: list, img: list, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """A stable start: centred principal point, square pixels, radial k1, k2 only, from several
    focal-length guesses (OpenCV's own homography start diverged on far, weakly tilted views)."""
    w, h = size
    best = None
    for g in (0.5, 0.8, 1.3, 2.2, 4.0):
        f = g * max(w, h)
        K0 = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
        try:
            rms, K, D, *_ = _calibrate("radtan", obj, img, size, K0=K0, d0=np.zeros(5),
                                       extra_flags=cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_ZERO_TANGENT_DIST
                                       | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_ASPECT_RATIO)
        except cv2.error:
            continue
        if _plausible(K, size) and (best is None or rms < best[0]):
            best = (rms, K, D)
    if best is None:  # every start failed: let OpenCV's own start raise its reason
        _, K, D, *_ = _calibrate("radtan", obj, img, size, extra_flags=cv2.CALIB_FIX_PRINCIPAL_POINT
                                 | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3)
        return K, D
    return best[1], best[2]


def calibrate_camera(det: Detections, spec: BoardSpec, model: str = "radtan", max_views: int = 40,
                     fixed: Camera | None = None, min_views: int = 4, frames: np.ndarray | None = None
                     ) -> IntrinsicResult:
    """Intrinsics of one camera from its board detections (or ``fixed`` ones, only posed)."""
    require_solvable(model)
    usable = det.usable(spec) if frames is None else np.asarray(frames)
    name = det.camera
    if len(usable) < min_views:
        raise UserError(f"camera {name}: too few views of the board ({len(usable)} frames with at least 6 corners "
                        f"over two rows and columns, need {min_views})",
                        "record longer, with the board closer to this camera and fully in view")
    if fixed is not None:
        cam0 = fixed.copy(name=name)
    else:
        # initial intrinsics from a spread of the views with most corners
        order = usable[np.argsort(-det.n_corners_f[usable], kind="stable")]
        init = np.sort(order[np.linspace(0, len(order) - 1, min(25, len(order))).round().astype(int)])
        init = np.unique(init)
        obj = [spec.corners_b3[np.isfinite(det.xy_fn2[f, :, 0])] for f in init]
        img = [det.xy_fn2[f][np.isfinite(det.xy_fn2[f, :, 0])] for f in init]
        try:
            K, D = _initial_intrinsics(obj, img, det.size)
            if model == "rational":
                D = np.r_[D, np.zeros(3)]
            if model == "fisheye":
                _, K, D, *_ = _calibrate("fisheye", obj, img, det.size, K0=K, d0=np.zeros(4))
        except cv2.error as e:
            raise UserError(f"camera {name}: the board views are degenerate (OpenCV: {_cv_reason(e)})",
                            "tilt the board 30-45 degrees towards and away from the camera and cover the image") \
                from None
        cam0 = Camera(name, det.size, K, D, model)
    sel, sel_info = select_views(det, spec, cam0, usable, max_views)
    if len(sel) < min_views:
        raise UserError(f"camera {name}: too few usable views of the board ({len(sel)}, need {min_views})",
                        "record the board closer to this camera, still, at several places and tilts")
    tilts = np.array(list(sel_info["tilts"].values()))
    max_tilt = float(np.max(tilts)) if len(tilts) else 0.0
    if fixed is not None:
        rv, tv, errs = [], [], []
        for f in sel:
            r, t, e = board_pose(cam0, spec, det.xy_fn2[f])
            rv.append(r)
            tv.append(t)
            errs.append(e)
        return IntrinsicResult(cam0, float(np.sqrt(np.mean(np.square(errs)))), sel, np.array(errs), np.array(rv),
                               np.array(tv), {}, sel_info["coverage"], max_tilt, fixed=True)
    if max_tilt < 8.0:
        raise UserError(f"camera {name}: degenerate views, the board was only ever seen face-on "
                        f"(largest tilt {max_tilt:.0f} degrees), so focal length and distance cannot be separated",
                        "hold the board tilted 30-45 degrees towards and away from this camera in several views")
    # calibrate, drop outlier views and corners, calibrate again (keeping the last good
    # solution if a round makes things worse)
    mask = {int(f): np.isfinite(det.xy_fn2[f, :, 0]) for f in sel}
    removed = 0
    K, D = cam0.K, cam0.dist
    best = None
    extra = 0
    for rnd in range(5):
        obj = [spec.corners_b3[mask[int(f)]] for f in sel]
        img = [det.xy_fn2[f][mask[int(f)]] for f in sel]
        try:
            out = _calibrate(model, obj, img, det.size, K0=K, d0=D, extra_flags=extra)
        except cv2.error as e:
            if best is not None:
                break
            raise UserError(f"camera {name}: calibration failed on degenerate views "
                            f"({_cv_reason(e)})",
                            "tilt the board 30-45 degrees in several views and cover the whole image") from None
        rms, K1, D1, rv, tv, std, errs = out
        sane = _plausible(K1, det.size)
        if not sane and best is None and not extra and model != "fisheye":
            # the free aspect ratio let the solver wander off: phones have square pixels
            log.warn(f"{name}: the free-aspect solution was implausible (fx {K1[0, 0]:.0f}, fy {K1[1, 1]:.0f} px); "
                     "calibrating with square pixels")
            extra = cv2.CALIB_FIX_ASPECT_RATIO
            continue
        if best is not None and (not sane or rms > best[1][0] * 1.05 + 0.02):
            break
        best = (sel.copy(), out, {k: v.copy() for k, v in mask.items()})
        K, D = K1, D1
        cam = Camera(name, det.size, K, D, model)
        res = [np.linalg.norm(_residuals(cam, o, i, r, t), axis=1) for o, i, r, t in zip(obj, img, rv, tv)]
        allr = np.concatenate(res)
        sigma = np.median(allr) / 1.1774  # 2D residual norms: median = 1.1774 sigma
        thr = max(4.0 * sigma, 0.3)
        view_rms = np.array([np.sqrt(np.mean(r ** 2)) for r in res])
        bad_view = view_rms > max(3.0 * np.median(view_rms), 0.3)
        if not bad_view.any() and all(r.max() <= thr for r in res):
            break
        keep = ~bad_view
        for k, (f, r) in enumerate(zip(sel, res)):
            idx = np.nonzero(mask[int(f)])[0]
            bad = idx[r > thr]
            removed += len(bad) if keep[k] else len(idx)
            mask[int(f)][bad] = False
        n = spec.squares_x - 1
        for k, f in enumerate(sel):
            ids = np.nonzero(mask[int(f)])[0]
            if len(ids) < 6 or len(np.unique(ids % n)) < 2 or len(np.unique(ids // n)) < 2:
                keep[k] = False
        if keep.sum() < min_views:
            break
        sel = sel[keep]
    sel, (rms, K, D, rv, tv, std, errs), mask = best
    cam = Camera(name, det.size, K, D, model)
    if std is None:
        std = intrinsic_std(cam, spec, [spec.corners_b3[mask[int(f)]] for f in sel],
                            [det.xy_fn2[f][mask[int(f)]] for f in sel], rv, tv)
    return IntrinsicResult(cam, float(rms), sel, np.asarray(errs, float), rv, tv, std, sel_info["coverage"],
                           max_tilt, removed_corners=removed)


def intrinsic_std(cam: Camera, spec: BoardSpec, obj: list, img: list, rv, tv) -> dict:
    """1-sigma of the intrinsics from the Gauss-Newton covariance of a single-camera
    calibration (used for fisheye, where OpenCV reports none)."""
    nd = len(cam.dist)
    p0 = np.r_[cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], cam.dist]

    def res_intr(p, o, i, r, t):
        c = cam.copy(K=np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1]]), dist=p[4:])
        return _residuals(c, o, i, r, t).ravel()

    def res_pose(q, o, i):
        return _residuals(cam, o, i, q[:3], q[3:]).ravel()

    # Schur complement over the per-view poses
    n = 4 + nd
    H = np.zeros((n, n))
    sse, m = 0.0, 0
    eps = 1e-6
    for o, i, r, t in zip(obj, img, rv, tv):
        r0 = res_intr(p0, o, i, r, t)
        Ji = np.stack([(res_intr(p0 + eps * max(1, abs(p0[k])) * np.eye(n)[k], o, i, r, t) - r0)
                       / (eps * max(1, abs(p0[k]))) for k in range(n)], 1)
        q0 = np.r_[r, t]
        Jp = np.stack([(res_pose(q0 + eps * np.eye(6)[k], o, i) - r0) / eps for k in range(6)], 1)
        A = Ji.T @ Ji
        B = Ji.T @ Jp
        C = Jp.T @ Jp
        H += A - B @ np.linalg.solve(C + 1e-12 * np.eye(6), B.T)
        sse += float(r0 @ r0)
        m += len(r0)
    dof = max(1, m - n - 6 * len(obj))
    cov = np.linalg.pinv(H) * (sse / dof)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    names = K_NAMES + coefficient_names(cam.model, nd)
    return {k: float(v) for k, v in zip(names, sd)}


def projection_difference(a: Camera, b: Camera, grid: int = 24, region_xy: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """How differently two intrinsics map the same rays, in px over the image.

    Pixels of ``a`` are back-projected to rays, the best rotation between the two cameras'
    rays is removed (a rotation is absorbed by the extrinsics), and the rays are projected
    with ``b``. Returns (xy_g2 grid pixels, diff_g (px)); with ``region_xy`` (observed
    pixels) grid points outside their convex hull are NaN: no lens model can be judged
    where it was never observed (polynomials extrapolate wildly there)."""
    w, h = a.size
    nx = grid
    ny = max(2, round(grid * h / w))
    xs = np.linspace(0.03 * w, 0.97 * w, nx)
    ys = np.linspace(0.03 * h, 0.97 * h, ny)
    xy_all = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    inside = np.ones(len(xy_all), bool)
    if region_xy is not None and len(region_xy) >= 3:
        hull = cv2.convexHull(np.asarray(region_xy, np.float32).reshape(-1, 1, 2))
        inside = np.array([cv2.pointPolygonTest(hull, (float(x), float(y)), False) >= 0 for x, y in xy_all])
    xy = xy_all[inside]
    ra = np.c_[undistort_points(a, xy), np.ones(len(xy))]
    ra /= np.linalg.norm(ra, axis=1, keepdims=True)
    rb = np.c_[undistort_points(b, xy), np.ones(len(xy))]
    rb /= np.linalg.norm(rb, axis=1, keepdims=True)
    use = np.ones(len(xy), bool)
    for _ in range(3):  # rotation fitted where the two agree (extrapolated corners may not)
        U, _, Vt = np.linalg.svd(rb[use].T @ ra[use])
        R = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt  # R ra ~ rb
        rr = ra @ R.T
        pb = b.normalized_to_pixels(distort_normalized(rr[:, :2] / rr[:, 2:], b.model, b.dist))
        diff = np.linalg.norm(pb - xy, axis=1)
        use = diff <= max(3.0 * np.median(diff), 1e-9)
    out = np.full(len(xy_all), np.nan)
    out[inside] = diff
    return xy_all, out


def cross_validate(det: Detections, spec: BoardSpec, result: IntrinsicResult, model: str) -> dict | None:
    """Calibrate two interleaved halves of the selected views; their projection difference
    over the image says how well the data pin the lens down (cf. mrcal)."""
    sel = result.views
    if len(sel) < 8:
        return None
    halves = [sel[0::2], sel[1::2]]
    cams = []
    for hv in halves:
        obj = [spec.corners_b3[np.isfinite(det.xy_fn2[f, :, 0])] for f in hv]
        img = [det.xy_fn2[f][np.isfinite(det.xy_fn2[f, :, 0])] for f in hv]
        try:
            _, K, D, *_ = _calibrate(model, obj, img, det.size, K0=result.camera.K, d0=result.camera.dist)
        except cv2.error:
            return None
        cams.append(Camera(det.camera, det.size, K, D, model))
    seen = det.xy_fn2[sel].reshape(-1, 2)
    xy, diff = projection_difference(cams[0], cams[1], region_xy=seen[np.isfinite(seen[:, 0])])
    d = diff[np.isfinite(diff)]
    if len(d) == 0:
        return None
    return {"xy": xy, "diff_px": diff, "median_px": float(np.median(d)), "p95_px": float(np.percentile(d, 95)),
            "max_px": float(d.max())}
