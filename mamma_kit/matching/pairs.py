"""Tracklet-to-tracklet epipolar distances between two views.

Every track of view a is compared with every track of view b over all the frames they share
(a tracklet, not one frame): frames of b are brought to the times of a's frames through the
clock models (linear interpolation between b's two neighbouring frames, else the nearest frame
within half a frame period), and for every landmark visible in both views (> 0.5, or in the more
visible half of its detection) the symmetric epipolar distance is taken on undistorted pixels.

Distances are measured in units of the person's height in that image (the extent of its
landmarks): a pixel distance divided by the height is, to first order, a metric distance from
the epipolar plane divided by the body height, so one set of thresholds holds from 192-px test
renders to 4K phones and for people near or far. Each landmark's distance is capped (``cap``)
before averaging so the few outliers a landmark detector makes cannot outvote the rest.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from mamma_kit.core.camera import Camera


@dataclass
class ViewTracks:
    """One view's landmark tracks, ready for matching.

    times_ref (T,) frame times on the reference clock; xy_tkl2 undistorted pixels;
    vis_tkl (T, K, L) bool visible and finite; valid_tk (T, K); height_tk (T, K) px.
    """

    name: str
    camera: Camera
    times_ref: np.ndarray
    period: float
    track_ids: np.ndarray
    xy_tkl2: np.ndarray
    vis_tkl: np.ndarray
    valid_tk: np.ndarray
    height_tk: np.ndarray

    @property
    def n_tracks(self) -> int:
        return len(self.track_ids)

    @classmethod
    def from_keypoints(cls, kt, camera: Camera, times_ref: np.ndarray, vis_threshold: float = 0.5,
                       min_height_px: float = 8.0) -> "ViewTracks":
        """From a core.tracks.KeypointTracks (the keypoint model's 33 points per track), like landmarks."""
        return cls.from_arrays(kt.camera, kt.track_ids, kt.xy, kt.valid, kt.visibility, camera, times_ref, vis_threshold,
                          min_height_px)

    @classmethod
    def from_landmarks(cls, lt, camera: Camera, times_ref: np.ndarray, vis_threshold: float = 0.5,
                       min_height_px: float = 8.0) -> "ViewTracks":
        """From a core.tracks.LandmarkTracks; pixels are undistorted with the camera's lens."""
        return cls.from_arrays(lt.camera, lt.track_ids, lt.xy, lt.valid, lt.visibility, camera, times_ref, vis_threshold,
                          min_height_px)

    @classmethod
    def from_arrays(cls, name, track_ids, xy_tkl2, valid_tk, vis_tkl, camera: Camera, times_ref, vis_threshold,
                    min_height_px, period: float | None = None) -> "ViewTracks":
        """From a track file's raw arrays: xy (T, K, L, 2) recorded px, valid (T, K), visibility
        (T, K, L); ``period``: the frame period (default: the median step of times_ref). Every
        frame is built on its own, so the frames of a long take can be built a window at a time."""
        xy = np.asarray(xy_tkl2, np.float64)
        valid = np.asarray(valid_tk, bool) & np.isfinite(xy).all(-1).any(-1)
        finite = np.isfinite(xy).all(-1)
        xy_und = np.full_like(xy, np.nan)
        if finite.any():
            xy_und[finite] = camera.undistort_pixels(xy[finite])
        v = np.where(finite, np.asarray(vis_tkl, np.float64), np.nan)
        # a detection always keeps its more visible half: the ranking of visibility carries the
        # self-occlusion even from a network whose probabilities sit below the threshold (a
        # landmark's projection is where it is, occluded or not, so the matcher loses little)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            v_half = np.nanmedian(v, -1, keepdims=True)  # (T, K, 1)
        vis = (v >= np.minimum(vis_threshold, v_half)) & finite & valid[..., None]
        ys = np.where(finite, xy[..., 1], np.nan)
        with np.errstate(all="ignore"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                height = np.nanmax(ys, -1) - np.nanmin(ys, -1)
        height = np.where(valid & np.isfinite(height), np.maximum(height, min_height_px), np.nan)
        times_ref = np.asarray(times_ref, np.float64)
        if period is None:
            period = float(np.median(np.diff(times_ref))) if len(times_ref) > 1 else 1.0
        return cls(name, camera, times_ref, period, np.asarray(track_ids, np.int64), xy_und, vis, valid, height)


@dataclass
class PairResult:
    """Per track pair (Ka, Kb): mean capped symmetric distance (height units), the same in px,
    shared landmark observations and shared frames."""

    distance: np.ndarray
    distance_px: np.ndarray
    shared_landmarks: np.ndarray
    shared_frames: np.ndarray


def resample_to(b: ViewTracks, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """View b's tracks at the given reference times.

    Returns xy (F, Kb, L, 2), vis (F, Kb, L), height (F, Kb), ok (F, Kb): linear interpolation
    between b's neighbouring frames when the track is valid in both and they are at most 1.5
    periods apart, else b's nearest frame when it is within half a period.
    """
    tb = b.times_ref
    F = len(times)
    Kb, L = b.xy_tkl2.shape[1:3]
    if len(tb) == 0 or F == 0:
        return (np.full((F, Kb, L, 2), np.nan), np.zeros((F, Kb, L), bool), np.full((F, Kb), np.nan),
                np.zeros((F, Kb), bool))
    j1 = np.clip(np.searchsorted(tb, times), 1, max(len(tb) - 1, 1)) if len(tb) > 1 else np.zeros(F, np.int64)
    j0 = np.maximum(j1 - 1, 0)
    gap = tb[j1] - tb[j0]
    alpha = np.where(gap > 0, (times - tb[j0]) / np.where(gap > 0, gap, 1.0), 0.0)
    inside = (alpha >= -1e-9) & (alpha <= 1 + 1e-9) & (gap <= 1.5 * b.period)
    near = np.where(np.abs(tb[j0] - times) <= np.abs(tb[j1] - times), j0, j1)
    near_ok = np.abs(tb[near] - times) <= 0.5 * b.period + 1e-9
    both = b.valid_tk[j0] & b.valid_tk[j1] & inside[:, None]  # (F, Kb)
    a = alpha[:, None, None, None]
    xy_i = (1 - a) * b.xy_tkl2[j0] + a * b.xy_tkl2[j1]
    vis_i = b.vis_tkl[j0] & b.vis_tkl[j1]
    h_i = (1 - alpha[:, None]) * b.height_tk[j0] + alpha[:, None] * b.height_tk[j1]
    use_near = ~both & near_ok[:, None] & b.valid_tk[near]
    xy = np.where(both[..., None, None], xy_i, np.where(use_near[..., None, None], b.xy_tkl2[near], np.nan))
    vis = np.where(both[..., None], vis_i, use_near[..., None] & b.vis_tkl[near])
    h = np.where(both, h_i, np.where(use_near, b.height_tk[near], np.nan))
    return xy, vis, h, both | use_near


def _lines(F_33: np.ndarray, xy_n2: np.ndarray) -> np.ndarray:
    """Epipolar lines F x (..., 3), each scaled so (a, b) has unit norm (NaN where degenerate)."""
    l = xy_n2[..., 0:1] * F_33[:, 0] + xy_n2[..., 1:2] * F_33[:, 1] + F_33[:, 2]
    n = np.sqrt(l[..., 0] * l[..., 0] + l[..., 1] * l[..., 1])[..., None]
    return l / np.where(n > 1e-15, n, np.nan)


def _chunk_distances(a: ViewTracks, b: ViewTracks, sel: np.ndarray, F_ab: np.ndarray, cap: float):
    """At a's frames ``sel`` (f,): per track pair and landmark, whether both views see it
    (f, Ka, Kb, L), its capped symmetric epipolar distance in person heights, the same in px
    and the px cap."""
    xb, vb, hb, okb = resample_to(b, a.times_ref[sel])
    xa, va, ha = a.xy_tkl2[sel], a.vis_tkl[sel], a.height_tk[sel]
    lb = _lines(F_ab, xa)  # (f, Ka, L, 3) lines in b
    la = _lines(F_ab.T, xb)  # (f, Kb, L, 3) lines in a
    # point-line distances for every track pair: (f, Ka, Kb, L), a x + b y + c written out (an
    # einsum over a length-2 axis costs several times the arithmetic)
    xb_, lb_ = xb[:, None], lb[:, :, None]
    db = np.abs(xb_[..., 0] * lb_[..., 0] + xb_[..., 1] * lb_[..., 1] + lb_[..., 2])
    xa_, la_ = xa[:, :, None], la[:, None]
    da = np.abs(xa_[..., 0] * la_[..., 0] + xa_[..., 1] * la_[..., 1] + la_[..., 2])
    both = va[:, :, None, :] & vb[:, None, :, :] & okb[:, None, :, None]
    rel = 0.5 * (da / ha[:, :, None, None] + db / hb[:, None, :, None])
    finite = np.isfinite(rel)
    both &= finite
    cap_px = cap * (ha[:, :, None, None] + hb[:, None, :, None]) / 2
    return both, np.minimum(np.where(finite, rel, cap), cap), 0.5 * (da + db), cap_px


def frame_distances(a: ViewTracks, b: ViewTracks, cap: float = 0.25, min_per_frame: int = 5,
                    chunk: int = 32) -> np.ndarray:
    """(T_a, Ka, Kb) per frame of a, the mean capped epipolar distance (person heights) of
    every track pair at that instant; NaN where fewer than ``min_per_frame`` points are seen by
    both (one frame's version of pair_distances)."""
    Ka, Kb = a.n_tracks, b.n_tracks
    out = np.full((len(a.times_ref), Ka, Kb), np.nan)
    if Ka == 0 or Kb == 0 or not len(b.times_ref):
        return out
    F_ab = a.camera.fundamental_to(b.camera)
    ta = np.flatnonzero(a.valid_tk.any(1))
    for c0 in range(0, len(ta), chunk):
        sel = ta[c0:c0 + chunk]
        both, rel, _, _ = _chunk_distances(a, b, sel, F_ab, cap)
        n = both.sum(-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[sel] = np.where(n >= min_per_frame, np.where(both, rel, 0.0).sum(-1) / np.maximum(n, 1), np.nan)
    return out


def pair_distances(a: ViewTracks, b: ViewTracks, cap: float = 0.25, max_frames: int = 150,
                   min_per_frame: int = 5, chunk: int = 16) -> PairResult:
    """Symmetric epipolar distances between every track of a and every track of b (see module doc)."""
    Ka, Kb = a.n_tracks, b.n_tracks
    dist_sum = np.zeros((Ka, Kb))
    px_sum = np.zeros((Ka, Kb))
    count = np.zeros((Ka, Kb), np.int64)
    frames = np.zeros((Ka, Kb), np.int64)
    if Ka == 0 or Kb == 0:
        z = np.zeros((Ka, Kb))
        return PairResult(np.full((Ka, Kb), np.nan), np.full((Ka, Kb), np.nan), z.astype(np.int64), z.astype(np.int64))
    F_ab = a.camera.fundamental_to(b.camera)  # x_b^T F x_a = 0
    ta = np.flatnonzero(a.valid_tk.any(1) & np.isfinite(a.times_ref)
                        & (a.times_ref >= b.times_ref[0] - 0.5 * b.period)
                        & (a.times_ref <= b.times_ref[-1] + 0.5 * b.period))
    if len(ta) > max_frames:  # tracklet evidence saturates long before every frame is used
        ta = ta[np.unique(np.round(np.linspace(0, len(ta) - 1, max_frames)).astype(int))]
    for c0 in range(0, len(ta), chunk):
        sel = ta[c0:c0 + chunk]
        both, rel, px, cap_px = _chunk_distances(a, b, sel, F_ab, cap)
        n_fij = both.sum(-1)
        dist_sum += np.where(both, rel, 0.0).sum((0, 3))
        px_sum += np.where(both, np.minimum(px, cap_px), 0.0).sum((0, 3))
        count += n_fij.sum(0)
        frames += (n_fij >= min_per_frame).sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        dist = np.where(count > 0, dist_sum / np.maximum(count, 1), np.nan)
        dpx = np.where(count > 0, px_sum / np.maximum(count, 1), np.nan)
    return PairResult(dist, dpx, count, frames)
