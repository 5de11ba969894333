"""The `pose` mask backend: people found and segmented by BlazePose, followed over time.

Per frame: the detector looks at the whole frame (and, every few frames, at overlapping square
tiles, for people too small in the whole frame); each person already followed keeps the ROI the
landmark model predicted for this frame; detections that no followed person explains start new
tracks. The landmark model then gives every followed person 33 points and a segmentation of its
ROI. A pixel the segmentations of two people both claim goes to the person whose skeleton is
nearer, and no person's mask reaches farther from its skeleton than a share of its size (the ROI
also holds other people and bystanders). After the video, tracks that do not overlap in time and
meet where one ends and the next starts are joined, and tracks too short to be anyone are
dropped. Which tracks are the capture's people (not a bystander, not a duplicate) is decided
across the views (`mamma-kit match`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from mamma_kit.core import log
from mamma_kit.core.tracks import MaskTracks
from mamma_kit.keypoints.estimator import MIN_FOLLOW_FLAG, MIN_POSE_FLAG
from mamma_kit.masks.base import CameraInput, MaskTrackBuilder, track_summary

# two detections (whole frame and a tile) whose ROI centres lie within this share of the side are
# one person: only one of them goes on to the landmark model
MATCH_SHARE = 0.2
# a skeleton is the same person as a track's last one when its points lie within this share of the
# track's ROI side (60 fps or 30 fps motion between two frames stays well inside)
TRACK_SHARE = 0.12
# a followed person unseen this long is given up: long enough to pass behind someone and keep the id,
# short enough that the track's stale ROI does not take whoever walks into it later (in seconds, not
# frames: 30 frames were half a second at 60 fps but three at 10 fps, where a track lost in a
# crossing came back on the other person)
MAX_MISSED_S = 0.5
# while hidden behind someone, a person keeps its visible sliver this long if it holds at least this
# share of its last full mask; such masks score COAST_SCORE
MAX_COAST_S = 0.5
MIN_COAST_AREA = 0.03
COAST_SCORE = 0.1
# the finer tiles: this share of the frame's short side, if at least MIN_TILE_PX
FINE_TILE_SHARE = 0.5
MIN_TILE_PX = 140
# a new track starts only from a skeleton the landmark model flags a person at least this surely
# (a followed one keeps going above MIN_FOLLOW_FLAG)
MIN_START_FLAG = 0.9
# tiles are looked at every this many frames (new people enter rarely; the detector costs 5 ms a call)
TILE_EVERY = 5
# a person's mask reaches at most this share of its ROI side from its skeleton
REACH_SHARE = 0.16
# two skeletons whose limb joints lie within this share of the ROI side (about 1.25 body heights)
# are one person
SAME_SHARE = 0.06
# the limb joints (shoulders, elbows, wrists, hips, knees, ankles) that tell people apart
BODY = np.r_[11:17, 23:29]
# frames longer than this are tracked at this size (4K at half size: the same crops and masks for the
# networks, a quarter of the per-pixel work; 1080p and smaller as they are)
WORK_SIDE = 1920
# the same joints with left and right swapped: BlazePose can swap sides on one person from one ROI
# to the next (a person seen from behind), which must not make two people of one
BODY_SWAPPED = np.r_[12, 11, 14, 13, 16, 15, 24, 23, 26, 25, 28, 27]
# shoulders and hips, and swapped; two skeletons whose torsos lie within this share of the torso's
# length of each other are one person
TORSO, TORSO_SWAPPED = np.r_[11, 12, 23, 24], np.r_[12, 11, 24, 23]
TORSO_SAME = 0.2
# two tracks' masks (before shared pixels are split) of which the smaller lies this much inside the
# larger are one body
SAME_BODY = 0.75


class _ScaledBuilder:
    """A MaskTrackBuilder at the video's size fed masks at the working size (nearest-neighbour up)."""

    def __init__(self, inner: MaskTrackBuilder, work_wh: tuple[int, int]):
        self.inner, self.work_wh = inner, tuple(work_wh)
        self.same = self.work_wh == tuple(inner.image_size)

    def add(self, t: int, track: int, mask_hw: np.ndarray, score: float = 1.0) -> None:
        if not self.same:
            mask_hw = cv2.resize(np.ascontiguousarray(mask_hw, np.uint8), tuple(self.inner.image_size),
                                 interpolation=cv2.INTER_NEAREST).view(bool)
        self.inner.add(t, track, mask_hw, score)


def torso_overlap(xy_a: np.ndarray, xy_b: np.ndarray) -> float:
    """Median distance of two skeletons' shoulders and hips (the smaller of as-is and sides swapped)
    over their mean torso length: below TORSO_SAME they are one body seen twice. Two people's
    torsos can coincide in an image only when one hides the other, and then the hidden one's
    skeleton is the front one's anyway; arms, which BlazePose places differently from one ROI to
    the next, do not count here."""
    a, b = xy_a[TORSO], xy_b[TORSO]
    d = min(np.median(np.linalg.norm(a - b, axis=1)), np.median(np.linalg.norm(a - xy_b[TORSO_SWAPPED], axis=1)))
    length = 0.5 * (torso_length(xy_a) + torso_length(xy_b))
    return float(d / max(length, 1.0))


def torso_length(xy_p2: np.ndarray) -> float:
    """Shoulder centre to hip centre (px)."""
    return float(np.linalg.norm(xy_p2[[11, 12]].mean(0) - xy_p2[[23, 24]].mean(0)))


def limb_distance(xy_a: np.ndarray, xy_b: np.ndarray) -> float:
    """Median distance (px) of two skeletons' limb joints, the smaller of as-is and sides swapped."""
    d = np.median(np.linalg.norm(xy_a[BODY] - xy_b[BODY], axis=1))
    d_sw = np.median(np.linalg.norm(xy_a[BODY] - xy_b[BODY_SWAPPED], axis=1))
    return float(min(d, d_sw))
# fragments are joined across a gap of at most this long where the boxes meet
JOIN_GAP_S = 0.25
JOIN_SHARE = 0.5
# tracks shorter than this are a glimpse or a false detection
MIN_TRACK_S = 0.2
SEG_THRESHOLD = 0.5


@dataclass
class _Track:
    tid: int
    roi: np.ndarray  # (4,) cx, cy, side, rotation for the coming frame
    xy: np.ndarray | None = None  # (33, 2) its last points
    area: int = 0  # its last mask's pixels
    missed: int = 0
    merged: bool = False  # its ROI found the body another track follows: a duplicate, not hidden


def tiles(W: int, H: int) -> np.ndarray:
    """(N, 4) overlapping square tiles (x1 y1 x2 y2): squares of the frame's short side along its
    longer side (none if square), then squares of FINE_TILE_SHARE of the short side over the whole
    frame, where those are at least MIN_TILE_PX: the detector finds people who fill a good part of
    its input, and a person a third of the frame's height fills too little of the whole frame."""
    out = []
    side = min(W, H)
    n = int(np.ceil(max(W, H) / side * 1.5)) if max(W, H) > 1.2 * side else 0
    if n >= 2:
        starts = np.linspace(0, max(W, H) - side, n)
        out += [[s, 0, s + side, side] if W >= H else [0, s, side, s + side] for s in starts]
    fine = FINE_TILE_SHARE * side
    if fine >= MIN_TILE_PX:
        xs = np.linspace(0, W - fine, max(2, int(np.ceil(W / fine * 1.5))))
        ys = np.linspace(0, H - fine, max(2, int(np.ceil(H / fine * 1.5))))
        out += [[x, y, x + fine, y + fine] for y in ys for x in xs]
    return np.array(out, float).reshape(-1, 4)


def skeleton_distance(xy_p2: np.ndarray, weight_p: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """Distance (px) of every pixel of ``box`` to the person's bones (points weighted >= 0.3)."""
    from mamma_kit.keypoints.blazepose import SKELETON

    x0, y0, x1, y1 = box
    canvas = np.full((y1 - y0, x1 - x0), 255, np.uint8)
    off = np.array([x0, y0])
    for a, b in SKELETON:
        if weight_p[a] >= 0.3 and weight_p[b] >= 0.3:
            cv2.line(canvas, tuple(int(v) for v in xy_p2[a] - off), tuple(int(v) for v in xy_p2[b] - off), 0, 3)
    if canvas.min() == 255:
        return np.full(canvas.shape, np.inf, np.float32)
    return cv2.distanceTransform(canvas, cv2.DIST_L2, 3)


class PoseBackend:
    name = "pose"

    def __init__(self, threads: int | None = None):
        self.threads = threads
        self._est = None

    @property
    def est(self):
        if self._est is None:
            from mamma_kit.keypoints.estimator import PoseEstimator

            self._est = PoseEstimator(self.threads)
        return self._est

    # ---- one frame ----------------------------------------------------------------------------------
    def _detections(self, img: np.ndarray, t: int) -> np.ndarray:
        """(N, 4) ROIs of the people the detector finds in this frame."""
        H, W = img.shape[:2]
        est = self.est
        dets = [est.detect(img)]
        if t % TILE_EVERY == 0:
            tl = tiles(W, H)
            if len(tl):
                dets += est.detect_regions(img, tl, margin=1.0)
        rois = [est.rois_from_detections(d) for d in dets if len(d)]
        if not rois:
            return np.zeros((0, 4))
        rois = np.concatenate(rois)
        # the same person found in the frame and in a tile: keep one (the first, the whole frame's)
        keep = []
        for i, r in enumerate(rois):
            if all(np.linalg.norm(r[:2] - rois[j, :2]) > MATCH_SHARE * max(r[2], rois[j, 2]) for j in keep):
                keep.append(i)
        return rois[keep]

    @staticmethod
    def _distinct(res, order: np.ndarray) -> list[int]:
        """Candidates (in ``order`` of preference) that are not the same skeleton as a preferred one
        (limb joints or torsos: two people's heads can touch)."""
        keep: list[int] = []
        for n in order:
            same = any(limb_distance(res.xy[n], res.xy[m]) < SAME_SHARE * max(res.rois[n, 2], res.rois[m, 2])
                       or torso_overlap(res.xy[n], res.xy[m]) < TORSO_SAME for m in keep)
            if not same:
                keep.append(int(n))
        return keep

    @staticmethod
    def _skeleton_cost(tracks: list[_Track], res, cands: list[int]) -> np.ndarray:
        """(tracks, candidates) median distance of shared visible points / the track's ROI side."""
        cost = np.full((len(tracks), len(cands)), np.inf)
        for i, tr in enumerate(tracks):
            for j, n in enumerate(cands):
                cost[i, j] = limb_distance(tr.xy, res.xy[n]) / max(tr.roi[2], 1.0)
        return cost

    def _masks(self, res, chosen: np.ndarray, W: int, H: int) -> tuple[list[np.ndarray | None], list]:
        """Per chosen candidate, its bool mask (H, W): segmentation near its own skeleton, shared
        pixels to the nearest skeleton; and per candidate the (own mask, box) before sharing (or
        None)."""
        prob_full, dist_full = [], []
        for n in chosen:
            prob, (x0, y0) = res.segmentation_of(int(n), (W, H))
            h, w = prob.shape
            if h == 0 or w == 0:
                prob_full.append(None)
                dist_full.append(None)
                continue
            box = (x0, y0, x0 + w, y0 + h)
            dist = skeleton_distance(res.xy[n], res.presence[n], box)
            own = (prob > SEG_THRESHOLD) & (dist <= REACH_SHARE * res.rois[n, 2])
            prob_full.append((own, box))
            dist_full.append(dist)
        # nearest skeleton wins shared pixels
        masks: list[np.ndarray | None] = []
        for i, item in enumerate(prob_full):
            if item is None:
                masks.append(None)
                continue
            own, (x0, y0, x1, y1) = item
            m = np.zeros((H, W), bool)
            m[y0:y1, x0:x1] = own
            for j, other in enumerate(prob_full):
                if j == i or other is None:
                    continue
                o_own, (a0, b0, a1, b1) = other
                ix0, iy0, ix1, iy1 = max(x0, a0), max(y0, b0), min(x1, a1), min(y1, b1)
                if ix1 <= ix0 or iy1 <= iy0:
                    continue
                mine = dist_full[i][iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0]
                theirs = dist_full[j][iy0 - b0:iy1 - b0, ix0 - a0:ix1 - a0]
                both = m[iy0:iy1, ix0:ix1] & o_own[iy0 - b0:iy1 - b0, ix0 - a0:ix1 - a0]
                lose = both & ((theirs < mine) | ((theirs == mine) & (j < i)))
                m[iy0:iy1, ix0:ix1] &= ~lose
            masks.append(m)
        return masks, prob_full

    @staticmethod
    def _keep_masks(tracks: list[_Track], prev: dict[int, np.ndarray], W: int, H: int) -> list | None:
        """Per track, the pixels its landmark model may see: all but the other people's masks of the
        previous frame (outside its own), so a followed ROI does not slide onto a neighbour."""
        if not prev or len(tracks) < 2:
            return None
        out = []
        for tr in tracks:
            others = [m for tid, m in prev.items() if tid != tr.tid]
            if not others:
                out.append(None)
                continue
            blank = np.logical_or.reduce(others)
            if tr.tid in prev:
                blank &= ~prev[tr.tid]
            out.append(~blank)
        return out

    @staticmethod
    def _coast(tracks, got, res, source, builder, prev, ti: int, W: int, H: int, max_coast: int) -> None:
        """A followed person hidden behind another (its ROI's skeleton is the other's) keeps the
        pixels of its ROI's segmentation that are near its last skeleton and no one else's: the
        visible sliver, so its track does not break while it passes behind someone."""
        taken = [prev[tr.tid] for i, tr in enumerate(tracks) if i in got and tr.tid in prev]
        others = np.logical_or.reduce(taken) if taken else np.zeros((H, W), bool)
        for i, tr in enumerate(tracks):
            if i in got or tr.xy is None or tr.merged or not 0 < tr.missed <= max_coast:
                continue
            n = int(np.flatnonzero(source == i)[0])
            prob, (x0, y0) = res.segmentation_of(n, (W, H))
            if prob.size == 0:
                continue
            box = (x0, y0, x0 + prob.shape[1], y0 + prob.shape[0])
            near = skeleton_distance(tr.xy, np.ones(len(tr.xy)), box) <= REACH_SHARE * tr.roi[2]
            m = np.zeros((H, W), bool)
            m[y0:box[3], x0:box[2]] = (prob > SEG_THRESHOLD) & near
            m &= ~others
            if m.sum() >= MIN_COAST_AREA * max(tr.area, 1):
                builder.add(ti, tr.tid, m, COAST_SCORE)

    # ---- the video ------------------------------------------------------------------------------------
    def track_camera(self, cam: CameraInput) -> tuple[MaskTracks, dict]:
        from mamma_kit.video.reader import VideoReader

        rd = VideoReader(cam.video, cam.rotation)
        times = rd.timestamps
        # the networks see 224-256 px crops and their masks come at 256x256: tracking works on frames
        # at most WORK_SIDE long (a 4K frame at half size, smaller ones as they are) and only the
        # masks kept are scaled up to the video's size
        W, H = rd.working_size(WORK_SIDE)
        est = self.est
        builder = _ScaledBuilder(MaskTrackBuilder(cam.name, rd.size, times), (W, H))
        tracks: list[_Track] = []
        next_id = 0
        max_missed, max_coast = frames_in(MAX_MISSED_S, times), frames_in(MAX_COAST_S, times)
        prev: dict[int, np.ndarray] = {}  # track id -> its mask in the previous frame
        for t, img in log.track(rd.frames(max_side=WORK_SIDE), f"track {cam.name} (pose)", total=len(times)):
            ti = int(np.argmin(np.abs(times - t)))
            det = self._detections(img, ti)
            # candidates: every track's followed ROI (its last good one while missed) and every detection
            rois = np.concatenate([np.array([tr.roi for tr in tracks]).reshape(-1, 4), det])
            source = np.r_[np.arange(len(tracks)), np.full(len(det), -1)]
            keep = self._keep_masks(tracks, prev, W, H)
            keep = (keep + [None] * len(det)) if keep is not None else None
            res = est.landmarks(img, rois, masks=keep)
            good = np.flatnonzero(res.score >= np.where(source >= 0, MIN_FOLLOW_FLAG, MIN_POSE_FLAG))
            # the same skeleton found twice: keep the best-scoring candidate
            cands = self._distinct(res, good[np.argsort(-res.score[good])])
            cost = self._skeleton_cost(tracks, res, cands)
            gated = np.where(cost < TRACK_SHARE, cost, 1e3)
            r, c = linear_sum_assignment(gated) if gated.size else (np.zeros(0, int), np.zeros(0, int))
            got = {int(i): cands[int(j)] for i, j in zip(r, c) if gated[i, j] < 1e3}
            taken = set(got.values())
            # a skeleton no track explains starts one if a detection found it (not a drifted ROI) and
            # the landmark model is sure it is a person (furniture and posters can score 0.5-0.85)
            for n in cands:
                if n not in taken and source[n] < 0 and res.score[n] >= MIN_START_FLAG:
                    near = cost[:, cands.index(n)].min() if cost.shape[0] else np.inf
                    if near >= TRACK_SHARE:
                        tracks.append(_Track(next_id, res.rois[n]))
                        got[len(tracks) - 1] = n
                        next_id += 1
            order = sorted(got)
            masks, own = self._masks(res, np.array([got[i] for i in order], int), W, H)
            # two tracks on one body (two ROIs' skeletons that BlazePose placed apart on one person,
            # e.g. one cut off by the frame's edge; or a person passing behind another, whose ROI
            # finds the front one): the one whose body this is not gives it up
            drop = {give_up(tracks[order[a]].tid, own[a], tracks[order[b]].tid, own[b], prev)
                    for a, b in same_bodies(own)}
            if drop:
                for i in [i for i in order if tracks[i].tid in drop]:
                    del got[i]
                order = sorted(got)
                masks, _ = self._masks(res, np.array([got[i] for i in order], int), W, H)
            alive = []
            for i, tr in enumerate(tracks):
                if i in got:
                    n = got[i]
                    m = masks[order.index(i)]
                    if m is not None and m.any():
                        builder.add(ti, tr.tid, m, float(res.score[n]))
                        prev[tr.tid] = m
                        tr.area = int(m.sum())
                    tr.roi, tr.missed, tr.merged = res.next_rois[n], 0, False
                    tr.xy = res.xy[n]
                    alive.append(tr)
                elif tr.xy is None:  # started this frame on a body another track has: never was
                    continue
                else:  # keeps its last good ROI and points
                    prev.pop(tr.tid, None)
                    tr.missed += 1
                    # its own ROI's skeleton is a body another track has: two tracks on one person,
                    # so no sliver of that body is kept for it (see _coast)
                    n = np.flatnonzero(source == i)
                    tr.merged = tr.merged or tr.tid in drop or (len(n) > 0 and any(
                        torso_overlap(res.xy[n[0]], res.xy[m]) < TORSO_SAME for m in got.values()))
                    if tr.missed < max_missed:
                        alive.append(tr)
            self._coast(tracks, got, res, source, builder, prev, ti, W, H, max_coast)
            tracks = alive
        mt = builder.inner.build()
        summ = track_summary(mt)
        mt, chosen = keep_tracks(mt)
        summ.update({"detected_tracks": summ["tracks"], **track_summary(mt), "kept": chosen})
        return mt, summ


def give_up(tid_a: int, own_a, tid_b: int, own_b, prev: dict[int, np.ndarray]) -> int:
    """Of two tracks on one body (own: bool crop, (x0, y0, x1, y1) box), the one to give it up:
    the one whose last mask (``prev``: track id -> full-frame mask) it overlaps less (by IoU), as
    a person passing behind another has a small last mask elsewhere while the front one's last
    mask is this body; the younger one where neither has a last mask or they tie."""
    def iou(tid, own) -> float:
        last = prev.get(tid)
        if last is None or own is None:
            return -1.0
        m, (x0, y0, x1, y1) = own
        inter = np.count_nonzero(last[y0:y1, x0:x1] & m)
        union = np.count_nonzero(last) + np.count_nonzero(m) - inter
        return inter / union if union else 0.0

    ia, ib = iou(tid_a, own_a), iou(tid_b, own_b)
    if abs(ia - ib) < 0.05:
        return max(tid_a, tid_b)
    return tid_a if ia < ib else tid_b


def same_bodies(own: list) -> list[tuple[int, int]]:
    """Pairs (a, b) of candidates whose own masks (bool crop, (x0, y0, x1, y1) box) are one body:
    more than SAME_BODY of the smaller lies in the larger."""
    out = []
    for a in range(len(own)):
        for b in range(a + 1, len(own)):
            if own[a] is None or own[b] is None:
                continue
            (ma, (ax0, ay0, ax1, ay1)), (mb, (bx0, by0, bx1, by1)) = own[a], own[b]
            ix0, iy0, ix1, iy1 = max(ax0, bx0), max(ay0, by0), min(ax1, bx1), min(ay1, by1)
            if ix1 <= ix0 or iy1 <= iy0:
                continue
            inter = np.count_nonzero(ma[iy0 - ay0:iy1 - ay0, ix0 - ax0:ix1 - ax0]
                                     & mb[iy0 - by0:iy1 - by0, ix0 - bx0:ix1 - bx0])
            smaller = min(np.count_nonzero(ma), np.count_nonzero(mb))
            if smaller and inter > SAME_BODY * smaller:
                out.append((a, b))
    return out


# ---- after the video: join fragments, keep the capture's people --------------------------------------
def frames_in(seconds: float, times: np.ndarray) -> int:
    """How many frames of a video with these timestamps last ``seconds`` (at least 1)."""
    period = float(np.median(np.diff(times))) if len(times) > 1 else 1 / 30
    return max(1, int(round(seconds / max(period, 1e-6))))


def _centre_height(box_4: np.ndarray) -> tuple[np.ndarray, float]:
    return (box_4[:2] + box_4[2:]) / 2, float(box_4[3] - box_4[1])


def join_fragments(mt: MaskTracks) -> list[list[int]]:
    """Groups of columns that are one person seen in pieces (no overlap in time, meeting boxes)."""
    pres = mt.present
    join_gap = frames_in(JOIN_GAP_S, mt.frame_times)
    spans = [(int(np.flatnonzero(pres[:, k])[0]), int(np.flatnonzero(pres[:, k])[-1])) if pres[:, k].any()
             else (0, -1) for k in range(pres.shape[1])]
    groups = [[k] for k in range(pres.shape[1]) if spans[k][1] >= 0]
    changed = True
    while changed:
        changed = False
        best = None
        for a, ga in enumerate(groups):
            end = max(spans[k][1] for k in ga)
            ka = max(ga, key=lambda k: spans[k][1])
            for b, gb in enumerate(groups):
                if a == b:
                    continue
                start = min(spans[k][0] for k in gb)
                kb = min(gb, key=lambda k: spans[k][0])
                gap = start - end
                if not 0 < gap <= join_gap:
                    continue
                if (pres[:, ga].any(1) & pres[:, gb].any(1)).any():
                    continue
                ca, ha = _centre_height(mt.boxes[end, ka])
                cb, hb = _centre_height(mt.boxes[start, kb])
                d = np.linalg.norm(ca - cb) / max(ha, hb, 1.0)
                if d < JOIN_SHARE and (best is None or d < best[0]):
                    best = (d, a, b)
        if best is not None:
            _, a, b = best
            groups[a] = groups[a] + groups[b]
            del groups[b]
            changed = True
    return groups


def importance(mt: MaskTracks, cols: list[int]) -> float:
    """How much a (joined) track is one of the capture's people: its summed height over the frames
    (large and long-lived), times how much it moves and how far from the image's edge it stays."""
    pres = mt.present[:, cols].any(1)
    boxes = np.where(mt.present[:, cols, None], mt.boxes[:, cols], np.nan)
    box = np.nanmean(boxes[pres], axis=1)
    if not len(box):
        return 0.0
    W, H = mt.image_size
    h = box[:, 3] - box[:, 1]
    c = (box[:, :2] + box[:, 2:]) / 2
    move = float(np.nanmedian(np.linalg.norm(np.diff(c, axis=0), axis=1) / np.maximum(h[1:], 1))) if len(c) > 1 else 0
    edge = np.minimum.reduce([c[:, 0] / W, 1 - c[:, 0] / W, c[:, 1] / H, 1 - c[:, 1] / H])
    return float(np.nansum(h)) * (1.0 + 20.0 * min(move, 0.05)) * float(np.clip(np.nanmedian(edge) * 4, 0.25, 1.0))


def keep_tracks(mt: MaskTracks) -> tuple[MaskTracks, list[dict]]:
    """Join fragments and drop the shortest (shorter than MIN_TRACK_S: a glimpse or a false
    detection). No head count cuts tracks here: which tracks are the capture's people is
    decided across the views (`mamma-kit match --people`), since one view cannot tell a broken
    track, a duplicate and a bystander apart (AV16.3's meeting room: holding each view to 2
    tracks at once lost 10-15 % of the people's frames in two of the three cameras). Track ids
    are renumbered 0..K-1 by first appearance."""
    T = len(mt.frame_times)
    min_frames = max(2, min(frames_in(MIN_TRACK_S, mt.frame_times), T // 6))  # a clip under ~1 s: a sixth of it
    kept = []
    for g in join_fragments(mt):
        frames = mt.present[:, g].any(1)
        if frames.sum() >= min_frames:
            kept.append((importance(mt, g), g, frames))
    W, H = mt.image_size
    first = sorted(kept, key=lambda x: int(np.flatnonzero(x[2])[0]))
    builder = MaskTrackBuilder(mt.camera, (W, H), mt.frame_times)
    chosen = []
    for new_id, (score, g, frames) in enumerate(first):
        for t in np.flatnonzero(frames):
            for k in g:
                if mt.present[t, k]:
                    builder.add(int(t), new_id, mt.mask(int(t), k), float(mt.scores[t, k]))
        chosen.append({"track": new_id, "from": [int(mt.track_ids[k]) for k in g], "importance": round(score, 1),
                       "frames": int(frames.sum())})
    return builder.build(mt.producer), chosen
