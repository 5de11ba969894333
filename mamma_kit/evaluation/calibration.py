"""Calibration metrics against ground truth: per camera and worst case.

rotation_deg (angle of R_est R_gt^T), center_mm, focal_pct (mean of |fx|, |fy| relative
errors), principal_point_px, and reprojection_px (how differently the two cameras project
points 1-10 m in front of the rig, in px: all errors at once). The comparison is direct
when the calibration pinned its world frame to the floor board (diagnostics world.source
= "floor"); otherwise, or when ``align`` forces it, the estimate is first brought onto the
ground truth by the similarity (scale, rotation, translation) that best maps camera
centres and axes.
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
    pts_e, pts_g = [], []
    for n in names:
        for cam, pts in ((est[n], pts_e), (gt[n], pts_g)):
            C = cam.center
            pts += [C, C + cam.R[0], C + cam.R[1], C + cam.R[2]]
    pe, pg = np.array(pts_e), np.array(pts_g)
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


def compare(est: Rig, gt: Rig, align: bool) -> dict:
    names = [c.name for c in gt if c.name in est]
    if not names:
        raise UserError("the calibration shares no camera name with gt/calibration.toml",
                        "calibrate the workspace's own board videos")
    info = None
    if align:
        est, info = align_rig(est, gt)
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
        pe = e.project(X)
        reproj = np.linalg.norm(pe - xy, axis=1)
        per[n] = {"rotation_deg": rot, "center_mm": centre, "focal_pct": focal, "principal_point_px": pp,
                  "reprojection_px_mean": float(np.nanmean(reproj)), "reprojection_px_max": float(np.nanmax(reproj))}
    worst = {k: float(max(v[k] for v in per.values())) for k in next(iter(per.values()))}
    out = {"aligned": bool(align), "cameras": per, "worst": worst}
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


def evaluate_files(est_path: str | Path, gt_path: str | Path, align: bool | None = None) -> dict:
    """Direct comparison where the world is pinned to the floor (else aligned), plus the rig's
    own accuracy after alignment (``relative``) and, when pinned, the world frame's error."""
    est, diag = read_calibration(est_path)
    gt, _ = read_calibration(gt_path)
    pinned = diag.get("rig", {}).get("world", {}).get("source") == "floor"
    out = compare(est, gt, align if align is not None else not pinned)
    if pinned and align is None:
        rel = compare(est, gt, True)
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
