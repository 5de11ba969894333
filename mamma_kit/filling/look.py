"""Looking for a person where the other views say they are: BlazePose on the projected skeleton.

Per gap (filling/gaps.py) the landmark model runs on the square around the projected skeleton (grown
by ROI_GROW), the camera's own tracks' masks blanked (the person is not one of them: the tracks
there show someone else), then once more on the ROI its own points give. The person is taken as
found when the model flags a person (>= MIN_FLAG) whose limb joints lie near the projected ones
(median within AGREE_SHARE of the ROI's side: the body the other views see, not a neighbour the
ROI also holds); their mask is the segmentation near that skeleton outside the other tracks, as the
pose tracker builds it. Of two gaps of one frame that find one body, the one whose projection it
fits better keeps it; a body whose torso is where one of the camera's own tracks has its skeleton
that frame is that track's person (a neighbour whose mask did not cover them whole), not the gap's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.core import log
from mamma_kit.core.tracks import MaskTracks, encode_mask
from mamma_kit.filling.gaps import Gaps
from mamma_kit.masks.pose import REACH_SHARE, SEG_THRESHOLD, TORSO, limb_distance, skeleton_distance, torso_overlap

# the ROI: the projected skeleton's box, its longer side grown by this share (the probe on crowd-6,
# benchmarks/fill_feasibility.py: a quarter)
ROI_GROW = 1.25
MIN_FLAG = 0.5
AGREE_SHARE = 0.15
# a found mask of fewer pixels than this share of the skeleton's extent squared is a sliver (a whole
# person standing covers about 0.17 of it; crowd-6 seed 0: of the fills below 0.03, a quarter
# covered the true person with IoU >= 0.25, from 0.07 up all of them)
MIN_MASK_SHARE = 0.04
SAME_TORSO = 0.2


@dataclass
class Found:
    """A gap where the person was found: frame, person, mask (core.tracks.encode_mask: runs and box,
    so a long take's finds do not hold full frames) and the model's 33 points."""

    frame: int
    person: int
    mask: tuple
    points_p5: np.ndarray  # (33, 5) x, y, z, visibility, presence
    score: float
    agree: float  # limb-joint distance to the projection / ROI side


def roi_of(xy_n2: np.ndarray) -> np.ndarray:
    """(4,) cx, cy, side, rotation of the square around the finite points, grown by ROI_GROW."""
    xy = xy_n2[np.isfinite(xy_n2).all(1)]
    lo, hi = xy.min(0), xy.max(0)
    return np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, ROI_GROW * float(max(hi - lo)), 0.0])


def look_in_frame(est, img: np.ndarray, xy_g332: np.ndarray, blank_hw: np.ndarray | None,
                  tracked_n332: np.ndarray | None = None) -> list[tuple]:
    """For each projected skeleton of one frame: (score, agree, mask, points_p5) or None.
    ``tracked_n332``: the skeletons of the camera's own tracks in that frame (keypoints stage)."""
    H, W = img.shape[:2]
    rois = np.stack([roi_of(xy) for xy in xy_g332])
    masks = None if blank_hw is None else [~blank_hw] * len(rois)
    res = est.landmarks(img, rois, masks=masks)
    res = est.landmarks(img, res.next_rois, masks=masks)
    out = []
    for g in range(len(rois)):
        side = max(float(res.rois[g, 2]), 1.0)
        if res.score[g] < MIN_FLAG:
            out.append(None)
            continue
        proj = np.nan_to_num(xy_g332[g], nan=-1e6)  # an untriangulated joint never agrees
        agree = limb_distance(res.xy[g], proj) / side
        if agree > AGREE_SHARE:
            out.append(None)
            continue
        if tracked_n332 is not None and any(torso_overlap(res.xy[g], xy) < SAME_TORSO for xy in tracked_n332):
            out.append(None)
            continue
        prob, (x0, y0) = res.segmentation_of(g, (W, H))
        if prob.size == 0:
            out.append(None)
            continue
        box = (x0, y0, x0 + prob.shape[1], y0 + prob.shape[0])
        m = np.zeros((H, W), bool)
        near = skeleton_distance(res.xy[g], res.presence[g], box) <= REACH_SHARE * side
        m[y0:box[3], x0:box[2]] = (prob > SEG_THRESHOLD) & near
        if blank_hw is not None:
            m &= ~blank_hw
        extent = float(np.ptp(res.xy[g], axis=0).max())
        if m.sum() < MIN_MASK_SHARE * extent * extent:
            out.append(None)
            continue
        p5 = np.concatenate([res.xy[g], res.z[g, :, None], res.visibility[g, :, None], res.presence[g, :, None]], 1)
        out.append((float(res.score[g]), float(agree), m, p5))
    # one body found for two persons: the better fit keeps it
    for a in range(len(out)):
        for b in range(a + 1, len(out)):
            if out[a] is not None and out[b] is not None and torso_overlap(out[a][3][:, :2], out[b][3][:, :2]) < SAME_TORSO:
                if out[a][1] <= out[b][1]:
                    out[b] = None
                else:
                    out[a] = None
    return out


def look(est, reader, masks: MaskTracks, gaps: Gaps, label: str, keypoints=None) -> list[Found]:
    """Every gap of one camera looked for in its video (``reader``: a VideoReader of it; ``masks``: the
    camera's tracks, on the same frames as the gaps; ``keypoints``: their keypoint file, a
    core.trackrows.TrackFile, or None)."""
    from mamma_kit.core.tracks import nearest_frames

    if not len(gaps):
        return []
    vid_idx = nearest_frames(masks.frame_times, reader.timestamps)
    frames = sorted({int(f) for f in gaps.frame_g if vid_idx[f] >= 0})
    by_video = {int(vid_idx[f]): f for f in frames}
    found: list[Found] = []
    for i, _, img in log.track(reader.read_indices(sorted(by_video)), label, total=len(by_video)):
        f = by_video[i]
        g_idx = np.flatnonzero(gaps.frame_g == f)
        cols = np.flatnonzero(masks.present[f])
        blank = np.logical_or.reduce([masks.mask(f, int(k)) for k in cols]) if len(cols) else None
        tracked = None
        if keypoints is not None:  # frames ascend: the file is read forward once
            _, _, d = keypoints.rows(f, f + 1, keys=("xy",))
            tracked = d["xy"][np.isfinite(d["xy"][:, TORSO]).all((1, 2))]
        for g, r in zip(g_idx, look_in_frame(est, img, gaps.xy_g332[g_idx], blank, tracked)):
            if r is not None:
                enc = encode_mask(r[2])
                if enc is not None:
                    found.append(Found(f, int(gaps.person_g[g]), enc, r[3], r[0], r[1]))
    return found
