"""Person masks against ground truth: mean IoU per person, separated vs touching people.

Tracks are matched to ground-truth persons by IoU: per camera, each track goes to the gt person
with which its summed IoU over all frames is largest (several tracks may go to one person: a
track that ended and restarted). A person's mask in a frame is the union of its tracks' masks
there; its IoU with the gt mask is averaged over the frames where the person is visible
(gt area >= ``min_area`` px). A (frame, person) is *touching* when the person's gt mask, grown
by 1 % of the image height, meets another person's gt mask (contact or occlusion in the image),
else *separated*. Identity switches: frames where a track's best-IoU person changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.core.tracks import MaskTracks
from mamma_kit.core.workspace import Workspace


def pair_frames(times_a: np.ndarray, times_b: np.ndarray) -> np.ndarray:
    """For each time of a, the index of the nearest time of b within half a frame (else -1)."""
    a, b = np.asarray(times_a, float), np.asarray(times_b, float)
    if len(b) == 0:
        return np.full(len(a), -1, np.int64)
    tol = 0.5 * float(np.median(np.diff(b))) if len(b) > 1 else 1e-3
    j = np.clip(np.searchsorted(b, a), 1, max(len(b) - 1, 1)) if len(b) > 1 else np.zeros(len(a), np.int64)
    if len(b) > 1:
        j = np.where(np.abs(b[j - 1] - a) <= np.abs(b[j] - a), j - 1, j)
    return np.where(np.abs(b[j] - a) <= tol + 1e-9, j, -1).astype(np.int64)


def _stack(mt: MaskTracks, t: int, cols: np.ndarray, stride: int) -> np.ndarray:
    w, h = mt.image_size
    out = np.zeros((len(cols), (h + stride - 1) // stride, (w + stride - 1) // stride), bool)
    for i, k in enumerate(cols):
        m = mt.mask(t, int(k))
        if m is not None:
            out[i] = m[::stride, ::stride]
    return out


@dataclass
class CameraMaskEval:
    camera: str
    gt_ids: np.ndarray  # (P,)
    track_to_gt: dict  # track id -> gt person id (or -1)
    iou_tp: np.ndarray  # (T, P) IoU per frame and gt person (NaN where the person is not visible)
    touching_tp: np.ndarray  # (T, P) bool
    track_gt_frames: np.ndarray  # (T, K) gt person id each track overlaps best per frame (-1 none)
    switches: int
    # (T, P) IoU of the best single track per frame, whatever person it was given: segmentation
    # alone, without the tracker's identities (NaN where the person is not visible)
    best_track_iou_tp: np.ndarray
    iou_tkp: np.ndarray | None = None  # (T, K, P) IoU of every track with every gt person per gt frame


def compare_camera(pred: MaskTracks, gt: MaskTracks, min_area: int = 50, stride: int | None = None) -> CameraMaskEval:
    import cv2

    w, h = gt.image_size
    if stride is None:
        stride = 1 if w * h <= 1_000_000 else 2
    tg = pair_frames(gt.frame_times, pred.frame_times)
    T, P, K = len(gt.frame_times), len(gt.track_ids), len(pred.track_ids)
    inter_sum = np.zeros((K, P))
    per_frame_iou = np.full((T, K, P), np.nan)
    gt_masks: list = []
    pr_masks: list = []
    r = max(1, int(round(0.01 * h / stride)))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    touching = np.zeros((T, P), bool)
    gt_area = np.zeros((T, P))
    for t in range(T):
        g = _stack(gt, t, np.arange(P), stride)  # (P, h, w)
        gt_area[t] = g.reshape(P, -1).sum(1) * stride * stride
        if P > 1:
            grown = np.stack([cv2.dilate(gi.astype(np.uint8), kernel) > 0 for gi in g])
            others = g.sum(0)[None] - g  # pixels of the other persons
            touching[t] = (grown & (others > 0)).reshape(P, -1).any(1)
        p = _stack(pred, tg[t], np.arange(K), stride) if tg[t] >= 0 else np.zeros((K,) + g.shape[1:], bool)
        gf, pf = g.reshape(P, -1).astype(np.float32), p.reshape(K, -1).astype(np.float32)
        inter = pf @ gf.T  # (K, P)
        union = pf.sum(1)[:, None] + gf.sum(1)[None] - inter
        iou = np.where(union > 0, inter / np.maximum(union, 1), 0.0)
        per_frame_iou[t] = iou
        inter_sum += iou
        gt_masks.append(g)
        pr_masks.append(p)
    best = np.argmax(inter_sum, 1) if P else np.zeros(K, np.int64)
    assigned = np.where(inter_sum.max(1, initial=0) > 0, best, -1) if P else np.full(K, -1)
    iou_tp = np.full((T, P), np.nan)
    for t in range(T):
        g, p = gt_masks[t], pr_masks[t]
        for q in range(P):
            if gt_area[t, q] < min_area:
                continue
            mine = np.flatnonzero(assigned == q)
            u = p[mine].any(0) if len(mine) else np.zeros(g.shape[1:], bool)
            union = np.count_nonzero(u | g[q])
            iou_tp[t, q] = np.count_nonzero(u & g[q]) / union if union else np.nan
    # per frame: which gt person each track shows (IoU >= 0.1)
    fb = np.where(np.nan_to_num(per_frame_iou).max(2) >= 0.1, np.argmax(np.nan_to_num(per_frame_iou), 2), -1)
    sw = 0
    for k in range(K):
        seq = fb[:, k][fb[:, k] >= 0]
        sw += int(np.count_nonzero(seq[1:] != seq[:-1]))
    gt_ids = np.asarray(gt.track_ids, np.int64)
    t2g = {int(pred.track_ids[k]): (int(gt_ids[assigned[k]]) if assigned[k] >= 0 else -1) for k in range(K)}
    fb_ids = np.where(fb >= 0, gt_ids[np.clip(fb, 0, None)] if P else -1, -1)
    best_tp = np.where(np.isfinite(iou_tp), np.nan_to_num(per_frame_iou).max(1, initial=0.0), np.nan)
    return CameraMaskEval(pred.camera, gt_ids, t2g, iou_tp, touching, fb_ids, sw, best_tp,
                          np.nan_to_num(per_frame_iou).astype(np.float32))


def _mean(x) -> float | None:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return round(float(x.mean()), 4) if len(x) else None


def evaluate_cameras(ws: Workspace, cameras: list[str] | None = None) -> dict[str, CameraMaskEval]:
    cams = cameras or sorted(p.stem for p in ws.masks_dir.glob("*.npz"))
    out = {}
    for c in cams:
        gp = ws.gt_dir / "masks" / f"{c}.npz"
        if ws.mask_file(c).is_file() and gp.is_file():
            out[c] = compare_camera(MaskTracks.load(ws.mask_file(c)), MaskTracks.load(gp))
    return out


def summarize(evals: dict[str, CameraMaskEval]) -> dict:
    per_person: dict[int, list] = {}
    sep, touch, allv = [], [], []
    cams = {}
    for c, e in evals.items():
        for q, pid in enumerate(e.gt_ids):
            v = e.iou_tp[:, q]
            per_person.setdefault(int(pid), []).append(v)
            ok = np.isfinite(v)
            sep.append(v[ok & ~e.touching_tp[:, q]])
            touch.append(v[ok & e.touching_tp[:, q]])
            allv.append(v[ok])
        cams[c] = {"mean_iou": _mean(e.iou_tp), "tracks": len(e.track_to_gt), "id_switches": e.switches,
                   "track_to_gt": {str(k): v for k, v in e.track_to_gt.items()}}
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)  # noqa: E731
    return {
        "mean_iou": _mean(cat(allv)),
        "mean_iou_per_person": {str(p): _mean(cat(v)) for p, v in sorted(per_person.items())},
        "mean_iou_separated": _mean(cat(sep)), "mean_iou_touching": _mean(cat(touch)),
        "instances_separated": int(sum(len(x) for x in sep)), "instances_touching": int(sum(len(x) for x in touch)),
        "id_switches": int(sum(e.switches for e in evals.values())),
        "cameras": cams,
    }


def evaluate(ws: Workspace) -> dict | None:
    if not ws.masks_dir.is_dir() or not (ws.gt_dir / "masks").is_dir():
        return None
    evals = evaluate_cameras(ws)
    if not evals:
        return None
    return summarize(evals)
