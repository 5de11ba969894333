"""Fit metrics against ground truth: smplx/person_<k>.npz vs gt/smplx/person_<k>.npz.

- Time: the fit's frame_times are on the reference clock (its producer record names the
  reference camera); gt/timing.toml maps that camera's clock to scene time, in which the
  ground truth is sampled. Ground truth at the fit's instants: its own frame where the
  times coincide, else rotations slerped and translations interpolated between its frames.
- Space: results are in the calibration's world frame. When calibration.toml is not the
  ground truth's, the fit is first moved by the similarity that maps the estimated camera
  centres onto the true ones: the bodies are judged relative to the cameras, and the error of
  the world frame itself (where the floor board put it) is the calibration group's
  ``world_frame``.
- People: fit persons are matched to gt persons by the smallest mean joint distance.

Metrics (mm): MPJPE and PA-MPJPE (per-frame similarity alignment) over all 55 joints and
split into body (0-21) and hands (25-54); PVE over all mesh vertices and split into body
and hands (vertices whose dominant part is a hand); between people, the mean depth and
count of vertices of one person inside the other's closed proxy mesh (fit and gt); the
reprojection error per camera from the fit report.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mamma_kit.body import skeleton as sk
from mamma_kit.core.io import read_json
from mamma_kit.core.smplxfile import POSE_KEYS, SmplxResult, read_smplx_result
from mamma_kit.core.workspace import Workspace

BODY_JOINTS = np.arange(0, 22)
HAND_JOINTS = np.arange(25, 55)


# ---- time ------------------------------------------------------------------------------
def params_at(r: SmplxResult, times: np.ndarray) -> dict[str, np.ndarray]:
    """Parameters of a result at arbitrary times (within its span): its own frame where a
    time coincides (1 us), else per-joint slerp of rotations and linear translation."""
    from scipy.spatial.transform import Rotation, Slerp

    t = np.asarray(times, float)
    ft = r.frame_times
    out = {"betas": r.betas}
    i = np.clip(np.searchsorted(ft, t) - 1, 0, max(len(ft) - 2, 0))
    j = np.minimum(i + 1, len(ft) - 1)
    a = np.where(j > i, (t - ft[i]) / np.maximum(ft[j] - ft[i], 1e-12), 0.0)
    a = np.clip(a, 0.0, 1.0)
    exact = np.abs(ft[np.clip(np.round(np.interp(t, ft, np.arange(len(ft)))).astype(int), 0, len(ft) - 1)] - t) < 1e-6
    for k in POSE_KEYS:
        v = getattr(r, k)
        if k in ("transl", "expression"):
            out[k] = v[i] * (1 - a[:, None]) + v[j] * a[:, None]
            continue
        n = v.shape[1] // 3
        aa_i, aa_j = v[i].reshape(-1, n, 3), v[j].reshape(-1, n, 3)
        Ri, Rj = Rotation.from_rotvec(aa_i.reshape(-1, 3)), Rotation.from_rotvec(aa_j.reshape(-1, 3))
        rel = (Ri.inv() * Rj).as_rotvec() * np.repeat(a, n)[:, None]
        out[k] = (Ri * Rotation.from_rotvec(rel)).as_rotvec().reshape(len(t), n * 3)
    near = np.clip(np.round(np.interp(t, ft, np.arange(len(ft)))).astype(int), 0, len(ft) - 1)
    for k in POSE_KEYS:
        src = getattr(r, k)[near]
        out[k] = np.where(exact[:, None], src, out[k])
    return out


# ---- space -----------------------------------------------------------------------------
def _similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    try:  # the calibration stage's helper (Umeyama), when that stage is installed
        from mamma_kit.evaluation.calibration import similarity
    except ImportError:
        similarity = None
    if similarity is not None:
        return similarity(src, dst)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(b.T @ a / len(a))
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / max((a ** 2).sum() / len(a), 1e-12))
    return s, R, mu_d - s * R @ mu_s


def world_alignment(ws: Workspace) -> tuple[float, np.ndarray, np.ndarray, str]:
    """(s, R, t, how): X_gt = s R X_fit + t."""
    from mamma_kit.core.calibfile import read_calibration

    gt_path = ws.gt_dir / "calibration.toml"
    if not ws.calibration.is_file() or not gt_path.is_file():
        return 1.0, np.eye(3), np.zeros(3), "none (no calibration to compare)"
    est, diag = read_calibration(ws.calibration)
    gt, _ = read_calibration(gt_path)
    names = [n for n in est.names if n in gt]
    ce = np.stack([est[n].center for n in names])
    cg = np.stack([gt[n].center for n in names])
    if np.abs(ce - cg).max() < 1e-6:
        return 1.0, np.eye(3), np.zeros(3), "none (ground-truth calibration)"
    if len(names) < 3:
        return 1.0, np.eye(3), np.zeros(3), "none (fewer than 3 shared cameras)"
    s, R, t = _similarity(ce, cg)
    return s, R, t, "similarity on camera centres"


# ---- metrics ---------------------------------------------------------------------------
def procrustes_error(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Per-frame similarity-aligned errors: X, Y (T, J, 3) -> (T, J) |align(X) - Y|."""
    mx, my = X.mean(1, keepdims=True), Y.mean(1, keepdims=True)
    a, b = X - mx, Y - my
    S = np.einsum("tji,tjk->tik", b, a)
    U, sv, Vt = np.linalg.svd(S)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros_like(S)
    D[:, 0, 0] = D[:, 1, 1] = 1
    D[:, 2, 2] = d
    R = U @ D @ Vt
    s = np.einsum("tii->t", np.einsum("ti,tij->tij", sv, D)) / np.maximum((a ** 2).sum((1, 2)), 1e-12)
    Xa = s[:, None, None] * np.einsum("tij,tnj->tni", R, a) + my
    return np.linalg.norm(Xa - Y, axis=-1)


def penetration(model, verts_ptv3: np.ndarray, frames: np.ndarray | None = None, near: float = 0.05) -> dict:
    """Vertices of each person inside another person's closed proxy, per frame.

    verts (P, T, V, 3) full meshes. Vertices within ``near`` of one of the other's proxy
    vertices (the proxy's edges are ~3 cm, so this covers penetrations ~3 cm deep and more)
    get their closest triangle among those around their nearest proxy vertices and the
    inside/outside sign of the angle-weighted pseudo-normal there. Returns the mean depth
    (mm) over penetrating vertices, their mean count per frame, the largest depth and the
    number of frames with any penetration."""
    import torch
    from scipy.spatial import cKDTree

    from mamma_kit.fitting.contact import ContactConfig, ContactModel

    cm = ContactModel(model, ContactConfig(k_vertices=2))
    P, T = verts_ptv3.shape[:2]
    ids = model.proxy.vertex_ids
    depths, counts = [], np.zeros(T)
    max_d = 0.0
    frames = np.arange(T) if frames is None else np.asarray(frames)
    for t in frames:
        for a in range(P):
            for b in range(P):
                if a == b:
                    continue
                pb_np = verts_ptv3[b, t][ids]
                pts_np = verts_ptv3[a, t]
                lo, hi = pb_np.min(0) - near, pb_np.max(0) + near
                sel = np.flatnonzero(((pts_np >= lo) & (pts_np <= hi)).all(1))
                if not len(sel):
                    continue
                dn, nn = cKDTree(pb_np).query(pts_np[sel], k=cm.cfg.k_vertices)
                keep = dn[:, 0] < near
                if not keep.any():
                    continue
                sel, nn = sel[keep], nn[keep]
                with torch.no_grad():
                    _, sign, dist = cm._closest(torch.as_tensor(pts_np[sel], dtype=torch.float32),
                                                torch.as_tensor(pb_np, dtype=torch.float32)[None],
                                                torch.zeros(len(sel), dtype=torch.long), torch.as_tensor(nn))
                inside = dist[sign < 0].numpy()
                depths.append(inside)
                counts[t] += len(inside)
                if len(inside):
                    max_d = max(max_d, float(inside.max()))
    d = np.concatenate(depths) if depths else np.zeros(0)
    return {"mean_depth_mm": float(d.mean() * 1000) if len(d) else 0.0,
            "mean_vertices_per_frame": float(counts[frames].mean()) if len(frames) else 0.0,
            "max_depth_mm": max_d * 1000, "frames_with_penetration": int((counts[frames] > 0).sum()),
            "frames": int(len(frames))}


def match_people(fit: list[np.ndarray], gt: list[np.ndarray]) -> list[tuple[int, int]]:
    """(fit index, gt index) pairs with the smallest total mean joint distance; joints (T, J, 3)."""
    from scipy.optimize import linear_sum_assignment

    cost = np.array([[np.nanmean(np.linalg.norm(f - g, axis=-1)) for g in gt] for f in fit])
    r, c = linear_sum_assignment(np.nan_to_num(cost, nan=1e9))
    return list(zip(r.tolist(), c.tolist()))


@dataclass
class Matched:
    """Fit results beside the ground truth at the fit's frames that overlap it (module doc).

    keep (T,) the fit frames used; world(X) maps the fit's world onto the truth's; pairs
    (fit index, gt index); fit_joints / gt_joints per person (T', 55, 3) m, in the truth's
    world; gt_params per gt person, its parameters at the kept frames."""
    model: object
    keep: np.ndarray
    how_time: str
    how_world: str
    world: Callable[[np.ndarray], np.ndarray]
    pairs: list[tuple[int, int]]
    fit_joints: list[np.ndarray]
    gt_joints: list[np.ndarray]
    gt_params: list[dict]


def match_results(ws: Workspace, results: list[SmplxResult]) -> Matched | dict | None:
    """Fit results matched to ground truth in time, space and identity; None without ground
    truth, {"error": ...} when they cannot be compared."""
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.timingfile import read_timing

    gt_files = sorted((ws.gt_dir / "smplx").glob("person_*.npz"))
    if not results or not gt_files:
        return None
    gts = [read_smplx_result(p) for p in gt_files]
    ref = str(results[0].producer.get("reference", ""))
    times = results[0].frame_times
    scene_t = times
    how_t = "fit times are scene times"
    gt_timing = ws.gt_dir / "timing.toml"
    if gt_timing.is_file():
        clocks, info = read_timing(gt_timing)
        if ref in clocks:
            scene_t = clocks[ref].to_ref(times)
            how_t = f"reference camera {ref} through its true clock"
        elif ref != (info.get("reference") or "scene"):
            how_t = f"unknown reference '{ref}': fit times taken as scene times"
    lo = max(g.frame_times[0] for g in gts)
    hi = min(g.frame_times[-1] for g in gts)
    keep = (scene_t >= lo - 1e-6) & (scene_t <= hi + 1e-6)
    if not keep.any():
        return {"error": "the fit's frames do not overlap the ground truth in time"}
    s, R, t, how_w = world_alignment(ws)
    model = load_body_model("open")
    if results[0].body_model_sha256 != model.sha256:
        return {"error": f"fit made with body model {results[0].body_model_name}; ground truth uses "
                         f"{model.name}: compare joints only through the same model"}

    def world(X):
        return s * X @ R.T + t

    fitJ = [world(r.joints[keep]) for r in results]
    gt_prm = [params_at(g, scene_t[keep]) for g in gts]
    gtJ = [pose_mesh_np(model, prm)[1].astype(np.float64) for prm in gt_prm]
    return Matched(model, keep, how_t, how_w, world, match_people(fitJ, gtJ), fitJ, gtJ, gt_prm)


def evaluate_results(ws: Workspace, results: list[SmplxResult], penetration_frames: int | None = 60) -> dict | None:
    """Metrics for fit results (see module doc); None without ground truth."""
    from mamma_kit.body.lbs import pose_mesh_np

    m = match_results(ws, results)
    if not isinstance(m, Matched):
        return m
    model, keep, world, pairs, fitJ, gtJ, gt_prm = m.model, m.keep, m.world, m.pairs, m.fit_joints, m.gt_joints, \
        m.gt_params
    how_t, how_w = m.how_time, m.how_world
    hand_v = np.isin(model.vertex_part, [i for i, n in enumerate(sk.PART_NAMES) if n.endswith("hand")])
    per = []
    e_all, pa_all, v_all = [], [], []
    fit_verts, gt_verts = [], []
    for fi, gi in pairs:
        r = results[fi]
        fv, _ = pose_mesh_np(model, {**{k: v[keep] for k, v in r.params().items() if k != "betas"},
                                     "betas": r.betas})
        fv = world(fv.astype(np.float64))
        gv, _ = pose_mesh_np(model, {**{k: v for k, v in gt_prm[gi].items() if k != "betas"},
                                     "betas": gt_prm[gi]["betas"]})
        gv = gv.astype(np.float64)
        e = np.linalg.norm(fitJ[fi] - gtJ[gi], axis=-1) * 1000  # (T, 55)
        pa = procrustes_error(fitJ[fi], gtJ[gi]) * 1000
        ve = np.linalg.norm(fv - gv, axis=-1) * 1000  # (T, V)
        e_all.append(e)
        pa_all.append(pa)
        v_all.append(ve)
        fit_verts.append(fv)
        gt_verts.append(gv)
        per.append({"person": int(r.producer.get("person", fi)), "gt_person": gi, "frames": int(keep.sum()),
                    "mpjpe_mm": float(e.mean()), "mpjpe_body_mm": float(e[:, BODY_JOINTS].mean()),
                    "mpjpe_hands_mm": float(e[:, HAND_JOINTS].mean()), "pa_mpjpe_mm": float(pa.mean()),
                    "pve_mm": float(ve.mean())})
    E, PA, VE = np.concatenate(e_all), np.concatenate(pa_all), np.concatenate(v_all)
    out = {"time_mapping": how_t, "world_alignment": how_w, "frames": int(keep.sum()), "people": per,
           "mpjpe_mm": float(E.mean()), "mpjpe_body_mm": float(E[:, BODY_JOINTS].mean()),
           "mpjpe_hands_mm": float(E[:, HAND_JOINTS].mean()),
           "pa_mpjpe_mm": float(PA.mean()), "pa_mpjpe_body_mm": float(PA[:, BODY_JOINTS].mean()),
           "pa_mpjpe_hands_mm": float(PA[:, HAND_JOINTS].mean()),
           "pve_mm": float(VE.mean()), "pve_body_mm": float(VE[:, ~hand_v].mean()),
           "pve_hands_mm": float(VE[:, hand_v].mean())}
    if len(pairs) >= 2:
        T = int(keep.sum())
        frames = np.arange(T) if penetration_frames is None or T <= penetration_frames else \
            np.unique(np.linspace(0, T - 1, penetration_frames).round().astype(int))
        out["penetration"] = penetration(model, np.stack(fit_verts), frames)
        out["penetration_gt"] = penetration(model, np.stack(gt_verts), frames)
    rep = ws.smplx_dir / "fit_report.json"
    if rep.is_file():
        try:
            out["reprojection_px"] = read_json(rep).get("reprojection_px", {})
        except Exception:  # a damaged report only loses this entry
            pass
    return out


def evaluate(ws: Workspace) -> dict | None:
    """The fit group of `mamma-kit eval` (None without fit results or ground truth)."""
    files = ws.person_files()
    if not files or not (ws.gt_dir / "smplx").is_dir():
        return None
    return evaluate_results(ws, [read_smplx_result(p) for p in files])


def install_gt_calibration_and_timing(ws: Workspace, reference: str | None = None) -> Path:
    """Write calibration.toml and timing.toml of a synthetic workspace from its ground truth
    (clocks made relative to ``reference``, default the first camera), to isolate the fit
    from calibration and sync in tests and benchmarks. Returns the timing path."""
    import shutil

    from mamma_kit.core.clock import ClockModel
    from mamma_kit.core.timingfile import write_timing

    shutil.copyfile(ws.gt_dir / "calibration.toml", ws.calibration)
    from mamma_kit.core.timingfile import read_timing

    gt, _ = read_timing(ws.gt_dir / "timing.toml")
    ref = reference or next(iter(gt))
    r = gt[ref]
    clocks = {n: ClockModel(offset=(c.offset - r.offset) / (1 + r.rate), rate=(1 + c.rate) / (1 + r.rate) - 1,
                            source="gt", confidence=1.0) for n, c in gt.items()}
    return write_timing(ws.timing, clocks, reference=ref, method="gt",
                        diagnostics={"note": "ground-truth clocks relative to the reference camera"})
