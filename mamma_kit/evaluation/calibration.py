"""Calibration metrics against ground truth: per camera and worst case.

rotation_deg (angle of R_est R_gt^T), center_mm, focal_pct (mean of |fx|, |fy| relative
errors), principal_point_px, and reprojection_px (how differently the two cameras project
points 1-10 m in front of the true camera, in px: all errors at once; points that fall behind
the estimated camera have no image there and are counted in behind_camera_pct instead).

The two rigs are compared in one world frame, brought together by only what the calibration
cannot know (``aligned``):

- "floor": the calibration pinned its world to the floor board (diagnostics world.source =
  "floor"), so its up axis, height and scale are its own claims; where the board lay on the
  floor and how it was turned are not, so the estimate is first turned about the vertical and
  shifted along the floor onto the truth (``align_floor``);
- "similarity": otherwise (or when asked), the similarity (scale, rotation, translation) that
  best maps camera centres and axes (``align_rig``); ``relative`` gives it beside "floor" too:
  the rig's own shape, whatever its world frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mamma_kit.core.calibfile import read_calibration
from mamma_kit.core.camera import Rig
from mamma_kit.core.errors import UserError


def similarity(src_n3: np.ndarray, dst_n3: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama: (s, R, t) minimising |s R src + t - dst|^2."""
    mu_s, mu_d = src_n3.mean(0), dst_n3.mean(0)
    a, b = src_n3 - mu_s, dst_n3 - mu_d
    U, S, Vt = np.linalg.svd(b.T @ a / len(a))
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    var = (a ** 2).sum() / len(a)
    s = float(np.trace(np.diag(S) @ D) / var) if var > 0 else 1.0
    return s, R, mu_d - s * R @ mu_s


def align_rig(est: Rig, gt: Rig) -> tuple[Rig, dict]:
    """The estimate in the ground truth's world frame by a similarity fitted on the camera
    centres and points 1 m along each camera's axes."""
    names = [c.name for c in gt if c.name in est]
    pe, pg = _axis_points(est, gt, names)
    # scale from the camera centres (axes are unit length in both frames), then the rotation
    # and translation from centres and axis points together
    s = similarity(pe[0::4], pg[0::4])[0] if len(names) >= 2 else 1.0
    ce = pe[0::4].repeat(4, 0)
    pe_s = ce + (pe - ce) + (s - 1) * ce  # centres scaled, axis offsets kept at unit length
    mu_e, mu_g = pe_s.mean(0), pg.mean(0)
    U, _, Vt = np.linalg.svd((pg - mu_g).T @ (pe_s - mu_e))
    R = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    t = mu_g - R @ mu_e
    aligned = est.transformed(R, t, s)
    return aligned, {"scale": float(s), "rotation_deg": float(np.degrees(np.arccos(
        np.clip((np.trace(R) - 1) / 2, -1, 1)))), "translation_m": t.tolist(), "R": R.tolist()}


def _axis_points(est: Rig, gt: Rig, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(4 C, 3) camera centres and points 1 m along each camera's axes, in both rigs."""
    pts_e, pts_g = [], []
    for n in names:
        for cam, pts in ((est[n], pts_e), (gt[n], pts_g)):
            C = cam.center
            pts += [C, C + cam.R[0], C + cam.R[1], C + cam.R[2]]
    return np.array(pts_e), np.array(pts_g)


def align_floor(est: Rig, gt: Rig) -> tuple[Rig, dict]:
    """The estimate turned about the world's vertical (Z) and shifted along the floor onto the
    truth (2D Procrustes of the camera centres and axis points' X, Y): its tilt, height and scale
    stay as calibrated, so they count in the errors."""
    names = [c.name for c in gt if c.name in est]
    pe, pg = _axis_points(est, gt, names)
    a, b = pe[:, :2] - pe[:, :2].mean(0), pg[:, :2] - pg[:, :2].mean(0)
    U, _, Vt = np.linalg.svd(b.T @ a)
    R2 = U @ np.diag([1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    R = np.eye(3)
    R[:2, :2] = R2
    t = np.zeros(3)
    t[:2] = pg[:, :2].mean(0) - R2 @ pe[:, :2].mean(0)
    return est.transformed(R, t, 1.0), {"yaw_deg": float(np.degrees(np.arctan2(R2[1, 0], R2[0, 0]))),
                                         "floor_shift_m": t[:2].tolist()}


ALIGNMENTS = ("none", "floor", "similarity")


def compare(est: Rig, gt: Rig, align: str = "similarity") -> dict:
    """Per-camera errors of ``est`` against ``gt`` after the alignment ``align`` (ALIGNMENTS)."""
    names = [c.name for c in gt if c.name in est]
    if not names:
        raise UserError("the calibration shares no camera name with gt/calibration.toml",
                        "calibrate the workspace's own board videos")
    if align not in ALIGNMENTS:
        raise ValueError(f"align must be one of {ALIGNMENTS}, not {align!r}")
    info = None
    if align == "similarity":
        est, info = align_rig(est, gt)
    elif align == "floor":
        est, info = align_floor(est, gt)
    per = {}
    rng = np.random.default_rng(0)
    for n in names:
        e, g = est[n], gt[n]
        dR = e.R @ g.R.T
        rot = float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))))
        centre = float(np.linalg.norm(e.center - g.center) * 1000)
        focal = float(np.mean(np.abs([e.K[0, 0] / g.K[0, 0] - 1, e.K[1, 1] / g.K[1, 1] - 1])) * 100)
        pp = float(np.linalg.norm(e.K[:2, 2] - g.K[:2, 2]))
        # points in front of the true camera, spread over its image, 1-10 m deep
        w, h = g.size
        xy = rng.uniform([0, 0], [w - 1, h - 1], (400, 2))
        depth = rng.uniform(1.0, 10.0, 400)
        X = g.unproject(xy, depth)
        front = e.to_camera(X)[:, 2] > 1e-6  # a point behind the estimated camera has no image there
        reproj = np.linalg.norm(e.project(X[front]) - xy[front], axis=1) if front.any() else np.zeros(0)
        per[n] = {"rotation_deg": rot, "center_mm": centre, "focal_pct": focal, "principal_point_px": pp,
                  "reprojection_px_mean": float(np.nanmean(reproj)) if len(reproj) else None,
                  "reprojection_px_max": float(np.nanmax(reproj)) if len(reproj) else None,
                  "behind_camera_pct": float(100 * (1 - front.mean()))}
    worst = {k: (max(vals) if (vals := [v[k] for v in per.values() if v[k] is not None]) else None)
             for k in next(iter(per.values()))}
    out = {"aligned": align, "cameras": per, "worst": worst}
    if info:
        out["alignment"] = info
    return out


def world_frame_error(est: Rig, gt: Rig) -> dict:
    """How far the estimated world frame is from the true one: the similarity that maps the
    estimated camera centres and axes onto the true ones, as a tilt of Z (deg), a turn about
    Z (deg), the origin's offset (mm) and the scale error (%)."""
    _, info = align_rig(est, gt)
    s, R = info["scale"], np.asarray(info["R"])
    z = R @ np.array([0.0, 0.0, 1.0])
    tilt = float(np.degrees(np.arccos(np.clip(z[2], -1, 1))))
    x = R @ np.array([1.0, 0.0, 0.0])
    yaw = float(np.degrees(np.arctan2(x[1], x[0])))
    return {"tilt_deg": tilt, "yaw_deg": abs(yaw), "origin_mm": float(np.linalg.norm(info["translation_m"]) * 1000),
            "scale_pct": float(abs(s - 1) * 100)}


def evaluate_files(est_path: str | Path, gt_path: str | Path, align: str | None = None) -> dict:
    """The rigs compared after the alignment the calibration leaves open ("floor" where it pinned
    its world to the floor board, else "similarity"; ``align`` forces one), plus the rig's own
    accuracy after a similarity (``relative``) and, when pinned, the world frame's error."""
    est, diag = read_calibration(est_path)
    gt, _ = read_calibration(gt_path)
    pinned = diag.get("rig", {}).get("world", {}).get("source") == "floor"
    out = compare(est, gt, align or ("floor" if pinned else "similarity"))
    if pinned and align is None:
        rel = compare(est, gt, "similarity")
        out["relative"] = {"cameras": rel["cameras"], "worst": rel["worst"], "alignment": rel.get("alignment")}
        out["world_frame"] = world_frame_error(est, gt)
    return out


def evaluate(ws) -> dict | None:
    """The calibration group of `mamma-kit eval`: the workspace's calibration.toml against
    gt/calibration.toml (None when either is missing)."""
    gt = Path(ws.gt_dir) / "calibration.toml"
    if not Path(ws.calibration).is_file() or not gt.is_file():
        return None
    return evaluate_files(ws.calibration, gt)
