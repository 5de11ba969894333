"""Landmark metrics of a synthetic workspace: landmarks/<cam>.npz against gt/landmarks/<cam>.npz.

Tracks are matched to ground-truth persons per frame by mask overlap (masks/<cam>.npz against
gt/masks/<cam>.npz) when the landmark file has the masks' track ids; otherwise track ids that are
ground-truth person ids (e.g. `landmarks --source gt` without masks) are used directly.

Reported over all cameras: landmark error in px and in % of the person's box height (all landmarks /
visible ones), visibility accuracy (threshold 0.5), ROC AUC of person contact and floor contact.
"""

from __future__ import annotations

import numpy as np

from mamma_kit.core.tracks import LandmarkTracks, MaskTracks
from mamma_kit.core.workspace import Workspace
from mamma_kit.landmarks.gt import gt_box_heights, gt_landmarks_file, gt_masks_file, match_tracks_to_gt, nearest_frames
from mamma_kit.landmarks.metrics import landmark_metrics


def landmark_pairs(ws: Workspace, cam: str, pred: LandmarkTracks | None = None) -> tuple[dict, str] | None:
    """Matched (prediction, ground truth) arrays of one camera, flattened over instances; the
    prediction is landmarks/<cam>.npz unless given."""
    pred = LandmarkTracks.load(ws.landmarks_file(cam)) if pred is None else pred
    gt = LandmarkTracks.load(gt_landmarks_file(ws, cam))
    if pred.n_landmarks != gt.n_landmarks:
        return None
    gm_path, m_path = gt_masks_file(ws, cam), ws.mask_file(cam)
    gt_masks = MaskTracks.load(gm_path) if gm_path.is_file() else None
    T, K = pred.valid.shape
    masks = MaskTracks.load(m_path) if m_path.is_file() else None
    if masks is not None and gt_masks is not None and np.array_equal(masks.track_ids, pred.track_ids):
        tm = nearest_frames(pred.frame_times, masks.frame_times)
        _, col_m = match_tracks_to_gt(masks, gt_masks)
        to_gt = np.array([np.flatnonzero(gt.track_ids == i)[0] if (gt.track_ids == i).any() else -1
                          for i in gt_masks.track_ids] + [-1])
        col = np.where(tm[:, None] >= 0, col_m[np.clip(tm, 0, None)], -1)
        col = np.where(col >= 0, to_gt[col], -1)
        how = "mask overlap"
    elif np.isin(pred.track_ids, gt.track_ids).all():
        col = np.broadcast_to(np.array([np.flatnonzero(gt.track_ids == i)[0] for i in pred.track_ids])[None], (T, K))
        how = "gt ids"
    else:
        return None
    tg = nearest_frames(pred.frame_times, gt.frame_times)
    ok = pred.valid & (col >= 0) & (tg[:, None] >= 0)
    ti, ki = np.nonzero(ok)
    gti, gpi = tg[ti], col[ti, ki]
    keep = gt.valid[gti, gpi]
    ti, ki, gti, gpi = ti[keep], ki[keep], gti[keep], gpi[keep]
    heights = gt_box_heights(gt, gt_masks)[gti, gpi]
    d = {"xy_p": pred.xy[ti, ki], "sigma_p": pred.sigma[ti, ki], "xy_g": gt.xy[gti, gpi], "box_h": heights,
         "vis_g": gt.visibility[gti, gpi], "vis_p": pred.visibility[ti, ki],
         "con_g": gt.contact[gti, gpi], "con_p": pred.contact[ti, ki],
         "flo_g": gt.floor_contact[gti, gpi], "flo_p": pred.floor_contact[ti, ki]}
    d["index_p"], d["index_g"] = (ti, ki), (gti, gpi)  # (frame, column) of each pair in pred and gt
    d["gt_instances"] = int(gt.valid.sum())
    return d, how


def evaluate(ws: Workspace, preds: dict[str, LandmarkTracks] | None = None) -> dict | None:
    """The landmark group of `mamma-kit eval` (module doc); ``preds`` per camera in place of
    landmarks/<cam>.npz (benchmarks that try a change in memory)."""
    if not ws.landmarks_dir.is_dir() or not (ws.gt_dir / "landmarks").is_dir():
        return None
    cams = sorted(p.stem for p in ws.landmarks_dir.glob("*.npz") if gt_landmarks_file(ws, p.stem).is_file())
    if not cams:
        return None
    parts, per_cam = [], {}
    for cam in cams:
        res = landmark_pairs(ws, cam, (preds or {}).get(cam))
        if res is None:
            per_cam[cam] = {"matched": False, "reason": "other landmark count than the ground truth, or track ids "
                                                        "neither gt ids nor matchable by masks"}
            continue
        d, how = res
        parts.append(d)
        m = landmark_metrics(d["xy_p"], d["xy_g"], d["box_h"], d["vis_g"], d["vis_p"])
        per_cam[cam] = {"matched": True, "matched_by": how, "instances": m["instances"],
                        "gt_instances": d["gt_instances"], "error_px_visible": m["error_px_visible"],
                        "error_pct_box_visible": m["error_pct_box_visible"]}
    if not parts:
        return {"cameras": per_cam}
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k not in ("gt_instances", "index_p", "index_g")}
    out = landmark_metrics(cat["xy_p"], cat["xy_g"], cat["box_h"], cat["vis_g"], cat["vis_p"], cat["con_g"],
                           cat["con_p"], cat["flo_g"], cat["flo_p"])
    out["coverage"] = out["instances"] / max(1, sum(p["gt_instances"] for p in parts))
    out["cameras"] = per_cam
    return out
