"""Every camera's pose refined from the people it films: `mamma-kit calibrate WORKSPACE --people`.

A calibration can be a degree or two off for a camera (the board was far from it or seen at a
slant, the camera was nudged after the board session, another system's calibration of the same
rig): every fit then bends between the views, and no fit is right in that camera. The people
themselves are a calibration object seen by every view at once. After `match` has said who is who:

- observations: the body points BlazePose sees (nose, shoulders to feet; visibility >= MIN_VIS) in
  every track with a person, at up to MAX_FRAMES instants spread over the take (each view's points
  interpolated between its two frames around them: clocks offset by part of a frame see a moving
  person a step apart), undistorted once with each camera's lens (intrinsics and lens stay);
- unknowns: each camera's rotation and translation, and each person's points in each frame (3D),
  started from their triangulation (points two or more views see);
- a bundle adjustment (scipy's least_squares, sparse Jacobian) of the pixel errors, robust (soft L1,
  SIGMA_PX) and weighted by the visibility, with a prior holding each camera within PRIOR_DEG and
  PRIOR_M of its calibrated pose; the refined rig is put back in the calibration's world frame (the
  similarity that overlays the two rigs' cameras): the floor and scale stay where they were;
- only cameras the people say are off move: those from which the points the other cameras place
  lie OFF_FACTOR times the cameras' typical error after a trial adjustment of every camera (a camera
  whose pose is off stands out; BlazePose's own disagreements between views are spread over all
  cameras: on the demo's accurate board calibration, moving every camera made the fit worse, MPJPE
  39.8 -> 105 mm, and none stands out there); those are refined with the others held, and with none
  the calibration is left as it is. OFF_FACTOR is set between the two captures this was measured on;
  a rig whose cameras are all off by a similar amount shows none standing out.

The real lab recording in ../shared/real (its Qualisys calibration): cam01 and cam03 stand out and
are refined (benchmarks/heldout_view.py --people gives the held-out figures).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.core import log
from mamma_kit.core.camera import Rig, rotvec, triangulate_points
from mamma_kit.core.errors import UserError

BODY = np.r_[0, 11:33]  # nose, shoulders to feet (the face's ten points would weigh the head ten times)
MIN_VIS = 0.5
MAX_FRAMES = 200
SIGMA_PX = 3.0
PRIOR_DEG, PRIOR_M = 5.0, 0.5
# a camera is refined when the points the others place lie this many times the cameras' typical error
# from it (the demo's accurate cameras: 2.9-3.7 times; the lab's two off ones 6.8 and 9.7, its others 2.7-2.9)
OFF_FACTOR = 5.0


@dataclass
class Observations:
    """The people's points as the views see them: per observation its camera (rig order), its 3D
    point (a person, frame and body point), undistorted normalised coordinates and weight."""

    cam_o: np.ndarray  # (O,)
    point_o: np.ndarray  # (O,)
    xn_o2: np.ndarray  # (O, 2)
    xy_o2: np.ndarray  # (O, 2) px as recorded
    w_o: np.ndarray  # (O,)
    n_points: int


def people_observations(ws, rig: Rig, max_frames: int = MAX_FRAMES) -> Observations:
    """The matched people's BlazePose body points of the workspace (keypoints/, identities.json),
    at instants of the first camera's frames on the reference clock, each view's points
    interpolated between its two frames around them."""
    from mamma_kit.core.filled import load_identities
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import KeypointTracks

    missing = [c for c in rig.names if not ws.keypoints_file(c).is_file()]
    if missing or not ws.identities.is_file():
        raise UserError(f"calibrate --people needs keypoints/ and identities.json ({', '.join(missing) or 'no match'} "
                        f"missing)", "run `mamma-kit capture-to-smplx WORKSPACE --to match` first")
    ident = load_identities(ws)
    clocks = read_timing(ws.timing)[0] if ws.timing.is_file() else {}
    kts = {c: KeypointTracks.load(ws.keypoints_file(c)) for c in rig.names}
    which = BODY
    times = {c: clocks[c].to_ref(kt.frame_times) if c in clocks else kt.frame_times for c, kt in kts.items()}
    grid = times[rig.names[0]]
    grid = grid[np.unique(np.linspace(0, len(grid) - 1, min(max_frames, len(grid))).round().astype(int))]
    cam_o, key_o, xy_o, w_o = [], [], [], []
    for ci, c in enumerate(rig.names):
        kt, tc = kts[c], times[c]
        if len(tc) < 2:
            continue
        period = float(np.median(np.diff(tc)))
        person_tk = ident.person_frames(c, kt.track_ids, tc)
        # each view's points at the grid's instants, between its two frames around them: cameras
        # whose frames are not taken together (a clock offset) see people a moving step apart
        f1_g = np.clip(np.searchsorted(tc, grid), 1, len(tc) - 1)
        f0_g = f1_g - 1
        inside = (grid >= tc[0]) & (grid <= tc[-1]) & (tc[f1_g] - tc[f0_g] <= 1.5 * period)
        for g in np.flatnonzero(inside):
            f0, f1 = f0_g[g], f1_g[g]
            a = (grid[g] - tc[f0]) / (tc[f1] - tc[f0])
            both = kt.valid[f0] & kt.valid[f1] & (person_tk[f0] >= 0) & (person_tk[f0] == person_tk[f1])
            for k in np.flatnonzero(both):
                vis = np.minimum(kt.visibility[f0, k, which], kt.visibility[f1, k, which])
                xy = (1 - a) * kt.xy[f0, k, which] + a * kt.xy[f1, k, which]
                ok = (vis >= MIN_VIS) & np.isfinite(xy).all(1)
                cam_o += [ci] * int(ok.sum())
                key_o += [(int(person_tk[f0, k]), int(g), int(j)) for j in which[ok]]
                xy_o.append(xy[ok])
                w_o.append(vis[ok])
    if not key_o:
        raise UserError("calibrate --people: no matched person's points in any view",
                        "check `mamma-kit match` found the people (report/match/)")
    keys, point_o = np.unique(np.array(key_o), axis=0, return_inverse=True)
    point_o = point_o.ravel()
    cam_o, xy, w = np.array(cam_o), np.concatenate(xy_o).astype(np.float64), np.concatenate(w_o).astype(np.float64)
    # a point two or more cameras see, once per camera (a person twice in one view: the first track)
    first = np.zeros(len(cam_o), bool)
    first[np.unique(point_o * len(rig) + cam_o, return_index=True)[1]] = True
    keep = first & (np.bincount(point_o[first], minlength=len(keys)) >= 2)[point_o]
    used, point_o = np.unique(point_o[keep], return_inverse=True)
    cam_o, xy, w = cam_o[keep], xy[keep], w[keep]
    xn = np.zeros_like(xy)
    for ci, c in enumerate(rig.names):
        m = cam_o == ci
        xn[m] = rig[c].pixels_to_lens(xy[m])
    return Observations(cam_o, point_o, xn, xy, w, len(used))


def refine_poses(rig: Rig, obs: Observations, free: list[str] | None = None, max_nfev: int = 200
                 ) -> tuple[Rig, dict]:
    """The rig with the poses of the cameras in ``free`` (None: all) refined from the observations
    (module doc; the others held where they are), and a report: per camera how far it moved and
    turned, and its median pixel error before and after."""
    from scipy.optimize import least_squares
    from scipy.sparse import coo_matrix
    from scipy.spatial.transform import Rotation

    from mamma_kit.evaluation.calibration import align_rig

    C, P, O = len(rig), obs.n_points, len(obs.cam_o)
    R0 = np.stack([c.R for c in rig])
    C0 = np.stack([c.center for c in rig])
    f_c = np.array([c.K[0, 0] for c in rig])
    xy_cp2 = points_by_camera(rig, obs)
    X0 = triangulate_points(rig, xy_cp2, np.isfinite(xy_cp2).all(-1).astype(float))
    sw = np.sqrt(obs.w_o)[:, None] * f_c[obs.cam_o, None] / SIGMA_PX
    hold = np.array([1.0 if free is None or c.name in free else 1e4 for c in rig])  # a held camera's prior

    def unpack(x):
        return x[:3 * C].reshape(C, 3), x[3 * C:6 * C].reshape(C, 3), x[6 * C:].reshape(P, 3)

    def residuals(x):
        rv, tv, X = unpack(x)
        R = Rotation.from_rotvec(rv).as_matrix()
        Xc = np.einsum("oij,oj->oi", R[obs.cam_o], X[obs.point_o]) + tv[obs.cam_o]
        r = (Xc[:, :2] / Xc[:, 2:3] - obs.xn_o2) * sw
        centre = -np.einsum("cji,cj->ci", R, tv)
        turned = Rotation.from_matrix(R @ R0.transpose(0, 2, 1)).as_rotvec()
        prior = np.c_[turned / np.radians(PRIOR_DEG), (centre - C0) / PRIOR_M] * hold[:, None]
        return np.r_[r.ravel(), prior.ravel()]

    # which unknowns each residual depends on: an observation on its camera's 6 and its point's 3
    o2 = np.repeat(np.arange(O), 2) * 2 + np.tile([0, 1], O)
    cols_cam = np.r_[np.arange(3), 3 * C + np.arange(3)]
    rows = [np.repeat(o2, 6), np.repeat(o2, 3), np.repeat(2 * O + np.arange(6 * C), 6)]
    cols = [(np.repeat(obs.cam_o, 2)[:, None] * 3 + cols_cam[None]).ravel(),
            (6 * C + np.repeat(obs.point_o, 2)[:, None] * 3 + np.arange(3)[None]).ravel(),
            (np.repeat(np.arange(C), 6)[:, None] * 3 + cols_cam[None]).ravel()]
    S = coo_matrix((np.ones(sum(len(r) for r in rows)), (np.concatenate(rows), np.concatenate(cols))),
                   shape=(2 * O + 6 * C, 6 * C + 3 * P)).tocsr()
    S.data[:] = 1
    x0 = np.r_[Rotation.from_matrix(R0).as_rotvec().ravel(), np.stack([c.t for c in rig]).ravel(), np.nan_to_num(X0).ravel()]
    res = least_squares(residuals, x0, jac_sparsity=S, loss="soft_l1", f_scale=1.0, x_scale="jac", method="trf",
                        max_nfev=max_nfev)
    rv, tv, X = unpack(res.x)
    R = Rotation.from_rotvec(rv).as_matrix()
    # the people fix the cameras relative to each other only: the refined rig is put back in the
    # calibration's world frame (the similarity that best overlays the two rigs' cameras: the held
    # ones where two or more are held), so what remains is what the views disagreed on, not a drift
    # of the whole rig
    loose = Rig([c.copy(R=R[i], t=tv[i]) for i, c in enumerate(rig)])
    held = [c.name for c in rig if free is not None and c.name not in free]
    _, gauge = align_rig(loose.subset(held), rig.subset(held)) if len(held) >= 2 else align_rig(loose, rig)
    cams = loose.transformed(np.asarray(gauge["R"]), np.asarray(gauge["translation_m"]), gauge["scale"])
    X = gauge["scale"] * X @ np.asarray(gauge["R"]).T + np.asarray(gauge["translation_m"])
    report = {"observations": O, "points": P, "iterations": int(res.nfev), "converged": bool(res.status > 0),
              "refined": [c.name for c in rig] if free is None else [str(n) for n in free],
              "prior": {"deg": PRIOR_DEG, "m": PRIOR_M}, "cameras": {}}
    for i, (old, new) in enumerate(zip(rig, cams.cameras)):
        # before: against the points the other cameras place (a camera that is off does not pull
        # them towards itself); after: against the adjusted points
        before = error_from_others(rig, xy_cp2, i)
        m = obs.cam_o == i
        after = np.linalg.norm(new.project(X[obs.point_o[m]]) - obs.xy_o2[m], axis=1)
        report["cameras"][old.name] = {
            "moved_m": round(float(np.linalg.norm(new.center - old.center)), 4),
            "turned_deg": round(float(np.degrees(np.linalg.norm(rotvec(new.R @ old.R.T)))), 3),
            "median_px_before": None if before is None else round(before, 2),
            "median_px_after": round(float(np.nanmedian(after)), 2) if np.isfinite(after).any() else None,
            "observations": int((obs.cam_o == i).sum())}
    return cams, report


def points_by_camera(rig: Rig, obs: Observations) -> np.ndarray:
    """(C, P, 2) each camera's pixels of each point, NaN where it does not see it."""
    xy_cp2 = np.full((len(rig), obs.n_points, 2), np.nan)
    xy_cp2[obs.cam_o, obs.point_o] = obs.xy_o2
    return xy_cp2


def error_from_others(rig: Rig, xy_cp2: np.ndarray, c: int, without: set[int] = frozenset()) -> float | None:
    """Median px between camera c's points and where the other cameras (but ``without``) place them
    (triangulated, two views or more); None with fewer than two such cameras."""
    others = [j for j in range(len(rig)) if j != c and j not in without]
    if len(others) < 2:
        return None
    X = triangulate_points(Rig([rig.cameras[j] for j in others]), xy_cp2[others],
                           np.isfinite(xy_cp2[others]).all(-1).astype(float))
    e = np.linalg.norm(rig.cameras[c].project(X) - xy_cp2[c], axis=1)
    return float(np.nanmedian(e)) if np.isfinite(e).any() else None


def cameras_off(rig: Rig, obs: Observations, trial: dict) -> tuple[list[str], float]:
    """The cameras the people say are off, worst first: the points the other cameras place lie
    OFF_FACTOR times the cameras' typical error (after a refinement of every camera, ``trial``;
    at least SIGMA_PX) from them. One at a time, each found one left out of the others' points
    (an off camera would pull them towards itself and make the camera opposite it look off too)."""
    typical = max(float(np.median([d["median_px_after"] for d in trial["cameras"].values()
                                   if d["median_px_after"] is not None])), SIGMA_PX)
    xy_cp2 = points_by_camera(rig, obs)
    off: list[int] = []
    errs = {c: trial["cameras"][cam.name]["median_px_before"] for c, cam in enumerate(rig)}  # none left out yet
    while True:
        errs = {c: e for c, e in errs.items() if e is not None and c not in off}
        if not errs:
            break
        worst = max(errs, key=errs.get)
        if errs[worst] <= OFF_FACTOR * typical:
            break
        off.append(worst)
        errs = {c: error_from_others(rig, xy_cp2, c, set(off)) for c in range(len(rig)) if c not in off}
    return [rig.cameras[c].name for c in off], typical


def refine_workspace(ws, max_frames: int = MAX_FRAMES) -> dict:
    """calibration.toml's camera poses refined from the matched people (module doc); the file as it
    was kept beside it (calibration.before-people.toml; refined again, the one before the first
    refinement stays), the report in its diagnostics."""
    import shutil

    from mamma_kit.core.calibfile import camera_to_dict, read_calibration
    from mamma_kit.core.io import read_toml, write_toml
    from mamma_kit.core.manifest import StageManifest

    if not ws.calibration.is_file():
        raise UserError(f"{ws.root} has no calibration.toml", "calibrate first (`mamma-kit calibrate WORKSPACE`)")
    rig, _ = read_calibration(ws.calibration)
    obs = people_observations(ws, rig, max_frames)
    log.info(f"calibrate --people: {obs.n_points} points of the matched people, {len(obs.cam_o)} observations")
    # which cameras the people say are off (cameras_off): the demo's accurate board calibration
    # 10.4-12.6 px from the others' points against a typical 3.4 px after the trial: none
    _, trial = refine_poses(rig, obs)
    off, after = cameras_off(rig, obs, trial)
    if not off:
        log.info(f"calibrate --people: no camera stands out (the people's points lie "
                 f"{', '.join(str(d['median_px_before']) for d in trial['cameras'].values())} px from them; "
                 f"{OFF_FACTOR:g} x {after:.1f} px would): calibration.toml left as it is")
        return {"stage": "calibrate", "people": True, "output": str(ws.calibration), "before": None,
                **trial, "refined": []}
    new, report = refine_poses(rig, obs, free=off)
    before = ws.root / "calibration.before-people.toml"
    doc = read_toml(ws.calibration, "calibration file")
    if "people" not in doc.get("diagnostics", {}) or not before.is_file():  # refined again: the first stays
        shutil.copyfile(ws.calibration, before)
    for cam in new:
        d = doc["cameras"][cam.name]
        d.update({k: v for k, v in camera_to_dict(cam).items() if k in ("rvec", "t")})
    doc.setdefault("diagnostics", {})["people"] = report
    write_toml(ws.calibration, doc)
    # the board calibration's manifest keeps the refined file as its own output: capture-to-smplx
    # does not calibrate again from the board on its account
    StageManifest(ws.cache_dir, "calibrate", ws.root).update_outputs([ws.calibration])
    return {"stage": "calibrate", "people": True, "output": str(ws.calibration), "before": str(before), **report}


def refine_if_off(ws, rematch=None, force: bool = False) -> dict:
    """capture-to-smplx's look at the camera poses after `match`: refine_workspace (it changes
    calibration.toml only where a camera stands out), then ``rematch()`` (the match again on the
    refined poses) if it did. Cached in .cache/poses.json by the calibration, identities and
    keypoints it read, so a run that changed none of them does not look again. A workspace without
    BlazePose keypoints of matched people is left alone (nothing to look with)."""
    from mamma_kit.core.manifest import StageManifest

    cams = ws.load_capture().camera_names
    inputs = [ws.calibration, ws.identities] + [ws.keypoints_file(c) for c in cams]
    man = StageManifest(ws.cache_dir, "poses", ws.root)
    settings = {"off_factor": OFF_FACTOR, "max_frames": MAX_FRAMES}
    fresh = man.check(inputs, settings)
    if fresh.fresh and not force:
        return {**(man.load() or {}).get("summary", {}), "skipped": True, "reason": fresh.reason}
    if not ws.calibration.is_file() or not any(ws.keypoints_file(c).is_file() for c in cams):
        return {"skipped": True, "reason": "no calibration or keypoints to look with", "refined": []}
    try:
        res = refine_workspace(ws)
    except UserError as e:  # too few matched points: nothing to say
        return {"skipped": True, "reason": e.message, "refined": []}
    if res.get("before") is not None and rematch is not None:
        rematch()
    summary = {"refined": res.get("refined", []), "before": res.get("before"),
               "cameras": res.get("cameras", {})}
    man.record(inputs, settings, [ws.calibration], summary=summary)
    return {**summary, "skipped": False}

