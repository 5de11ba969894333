"""Ground-truth landmarks with realistic noise (`mamma-kit landmarks WS --source gt`) and the
track <-> ground-truth person matching shared with evaluation.

A synthetic workspace holds gt/landmarks/<cam>.npz (LandmarkTracks, track id = person id, contact
labels 0/1) and gt/masks/<cam>.npz. ``noisy_gt_landmarks`` writes landmarks/<cam>.npz as the network
would: for each (frame, track) of masks/<cam>.npz (when that file exists) the ground-truth person
whose mask covers most of the track's mask in that frame (at least half of it) -- matched per frame,
so a tracker's identity switch is reproduced as a network fed that mask would -- else the gt persons
themselves. Positions get isotropic Gaussian noise of ``noise`` px (or a percentage of each person's
box height), a fraction ``outliers`` of landmarks is replaced by a point drawn uniformly in the
person's box, sigma is the noise level on both axes (never larger for outliers: the fit must cope),
visibility is the renderer's, contacts are the labels.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.manifest import producer
from mamma_kit.core.tracks import LandmarkTracks, MaskTracks, nearest_frames  # noqa: F401 - re-exported
from mamma_kit.core.workspace import Workspace

MIN_SIGMA_PX = 0.5  # sigma floor when noise is 0 (the fit divides by sigma)


def gt_landmarks_file(ws: Workspace, cam: str) -> Path:
    return ws.gt_dir / "landmarks" / f"{cam}.npz"


def gt_masks_file(ws: Workspace, cam: str) -> Path:
    return ws.gt_dir / "masks" / f"{cam}.npz"


def parse_noise(text: str | float) -> tuple[float, bool]:
    """'2.5' -> (2.5 px, False); '1.2%' -> (0.012, True) (fraction of the box height)."""
    s = str(text).strip()
    m = re.fullmatch(r"([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(%?)", s)
    if not m:
        raise UserError(f"--noise '{text}' is neither pixels nor a percentage", "use e.g. --noise 2 or --noise 1.2%")
    v = float(m.group(1))
    return (v / 100.0, True) if m.group(2) else (v, False)


def _decode(mt: MaskTracks, t: int, k: int, stride: int) -> np.ndarray | None:
    m = mt.mask(t, k)
    return None if m is None else m[::stride, ::stride]


def match_tracks_to_gt(masks: MaskTracks, gt_masks: MaskTracks, min_cover: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Per mask frame and track, the gt column it shows.

    Returns (gt_frame (T,) index into gt frames or -1, gt_col (T, K) column of gt_masks.track_ids or -1):
    the gt person whose mask covers the largest fraction of the track's mask, if >= ``min_cover``.
    """
    if tuple(masks.image_size) != tuple(gt_masks.image_size):
        raise UserError(f"masks/{masks.camera}.npz is {masks.image_size}, gt masks are {gt_masks.image_size}",
                        "run `mamma-kit track` again on this workspace")
    tg = nearest_frames(masks.frame_times, gt_masks.frame_times)
    T, K = masks.present.shape
    col = np.full((T, K), -1, np.int64)
    w, h = masks.image_size
    stride = 2 if w * h > 1_000_000 else 1
    for t in np.flatnonzero((tg >= 0) & masks.present.any(1)):
        gp = np.flatnonzero(gt_masks.present[tg[t]])
        if not len(gp):
            continue
        g = np.stack([_decode(gt_masks, tg[t], p, stride) for p in gp])  # (P, h, w)
        for k in np.flatnonzero(masks.present[t]):
            m = _decode(masks, t, k, stride)
            area = m.sum()
            if area == 0:
                continue
            cover = (g & m[None]).sum((1, 2)) / area
            best = int(np.argmax(cover))
            if cover[best] >= min_cover:
                col[t, k] = gp[best]
    return tg, col


def gt_box_heights(gt: LandmarkTracks, gt_masks: MaskTracks | None) -> np.ndarray:
    """(T, P) box height px of each gt person: from its mask box, else from its landmarks' extent."""
    ys = gt.xy[..., 1]
    with np.errstate(all="ignore"):
        h_lm = np.nanmax(ys, -1) - np.nanmin(ys, -1) if ys.size else np.zeros(gt.valid.shape)
    h = np.where(np.isfinite(h_lm), h_lm, np.nan)
    if gt_masks is not None:
        tg = nearest_frames(gt.frame_times, gt_masks.frame_times)
        cols = np.array([np.flatnonzero(gt_masks.track_ids == i)[0] if (gt_masks.track_ids == i).any() else -1
                         for i in gt.track_ids])
        ok = (tg[:, None] >= 0) & (cols[None] >= 0)
        hb = np.full(h.shape, np.nan)
        b = gt_masks.boxes[np.clip(tg, 0, None)][:, np.clip(cols, 0, None)]  # (T, P, 4)
        hb[ok] = (b[..., 3] - b[..., 1])[ok]
        h = np.where(np.isfinite(hb), hb, h)
    return h


def gt_boxes(gt: LandmarkTracks) -> np.ndarray:
    """(T, P, 4) x1, y1, x2, y2 of each gt person's landmarks (the outlier box)."""
    with np.errstate(all="ignore"):
        lo = np.nanmin(gt.xy, axis=2)
        hi = np.nanmax(gt.xy, axis=2)
    return np.concatenate([lo, hi], -1)


def noisy_gt_landmarks(ws: Workspace, cam: str, noise: str | float = 0.0, outliers: float = 0.0, seed: int = 0,
                       command: str = "") -> tuple[LandmarkTracks, dict]:
    """Noisy ground-truth landmarks of one camera in the layout of masks/<cam>.npz (see module doc)."""
    gpath = gt_landmarks_file(ws, cam)
    if not gpath.is_file():
        raise UserError(f"{ws.root} has no ground-truth landmarks for {cam} ({ws.relative(gpath)})",
                        "--source gt works on synthetic workspaces made by `mamma-kit synth`")
    if not 0.0 <= outliers <= 1.0:
        raise UserError(f"--outliers {outliers} is not a fraction in [0, 1]", "use e.g. --outliers 0.05")
    value, relative = parse_noise(noise)
    gt = LandmarkTracks.load(gpath)
    gm_path = gt_masks_file(ws, cam)
    gt_masks = MaskTracks.load(gm_path) if gm_path.is_file() else None
    T_gt, P, L = gt.xy.shape[:3]
    mpath = ws.mask_file(cam)
    if mpath.is_file():
        masks = MaskTracks.load(mpath)
        if gt_masks is None:
            raise UserError(f"{ws.relative(mpath)} exists but the ground-truth masks {ws.relative(gm_path)} do not",
                            "regenerate the synthetic workspace, or delete masks/ to use gt person ids")
        tg, gcol_mask = match_tracks_to_gt(masks, gt_masks)
        # gt_masks column -> gt landmark column
        to_lm = np.array([np.flatnonzero(gt.track_ids == i)[0] if (gt.track_ids == i).any() else -1
                          for i in gt_masks.track_ids] + [-1])
        tl = nearest_frames(masks.frame_times, gt.frame_times)
        pcol = np.where(gcol_mask >= 0, to_lm[gcol_mask], -1)
        pcol = np.where(tl[:, None] >= 0, pcol, -1)
        frame_times, track_ids, image_size = masks.frame_times, masks.track_ids, masks.image_size
        matched_by = "mask overlap per frame"
    else:
        tl = np.arange(T_gt)
        pcol = np.broadcast_to(np.arange(P)[None], (T_gt, P)).copy()
        frame_times, track_ids, image_size = gt.frame_times, gt.track_ids, gt.image_size
        matched_by = "gt person ids"
    T, K = pcol.shape
    out = LandmarkTracks.empty(cam, image_size, frame_times, track_ids, L, gt.landmark_set,
                               f"gt(noise={noise}, outliers={outliers}, seed={seed})")
    tsafe, psafe = np.clip(tl, 0, None)[:, None].repeat(K, 1), np.clip(pcol, 0, None)
    valid = (pcol >= 0) & gt.valid[tsafe, psafe]
    ti, ki = np.nonzero(valid)
    src_t, src_p = tsafe[ti, ki], psafe[ti, ki]
    rng = np.random.default_rng([seed, _cam_seed(cam)])
    xy = gt.xy[src_t, src_p].astype(np.float64)  # (M, L, 2)
    if relative:
        hts = gt_box_heights(gt, gt_masks)[src_t, src_p]
        sig = value * np.where(np.isfinite(hts), hts, 0.0)
    else:
        sig = np.full(len(ti), value)
    xy = xy + rng.standard_normal(xy.shape) * sig[:, None, None]
    if outliers > 0 and len(ti):
        box = gt_boxes(gt)[src_t, src_p]  # (M, 4)
        u = rng.uniform(0, 1, xy.shape)
        far = box[:, None, :2] + u * (box[:, None, 2:] - box[:, None, :2])
        is_out = rng.uniform(0, 1, xy.shape[:2]) < outliers
        xy = np.where(is_out[..., None], far, xy)
    out.valid[ti, ki] = True
    out.xy[ti, ki] = xy
    out.sigma[ti, ki] = np.maximum(sig, MIN_SIGMA_PX)[:, None, None]
    out.visibility[ti, ki] = gt.visibility[src_t, src_p]
    out.contact[ti, ki] = gt.contact[src_t, src_p]
    out.floor_contact[ti, ki] = gt.floor_contact[src_t, src_p]
    out.producer = producer(command or f"landmarks --source gt --noise {noise} --outliers {outliers} --seed {seed}")
    summary = {"camera": cam, "frames": int(T), "tracks": int(K), "instances": int(len(ti)), "matched_by": matched_by,
               "noise_px_mean": float(np.mean(sig)) if len(sig) else 0.0, "outliers": outliers}
    return out, summary


def _cam_seed(cam: str) -> int:
    import zlib

    return zlib.crc32(cam.encode())
