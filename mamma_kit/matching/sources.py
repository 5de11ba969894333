"""One view of a take as matching reads it: a window of frames at a time.

Matching a take window by window (matching.windows) needs, for the whole take at once, only what
is small per frame: the frames' times, which tracks are present, and each detection's centroid
(where a chain of windows is in 3D). The landmarks themselves (512 points per detection) are
needed one window at a time. A ``ViewSource`` holds the first and reads the second on request:
from the track file as a stream (core.io.NpzRows, so a take of minutes costs the memory of a
window) or from a ViewTracks already in memory (tests, benchmarks).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

from mamma_kit.core.camera import Camera
from mamma_kit.matching.pairs import ViewTracks


def centroids(v: ViewTracks) -> np.ndarray:
    """(T, K, 2) the centroid of each detection's visible points (undistorted px), NaN where none."""
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        xy = np.where(v.vis_tkl[..., None], v.xy_tkl2, np.nan)
        n = np.isfinite(xy[..., 0]).sum(-1)
        c = np.nansum(np.nan_to_num(xy), -2) / np.maximum(n, 1)[..., None]
    return np.where((n > 0)[..., None], c, np.nan)


def take(v: ViewTracks, frames: np.ndarray | slice, cols: np.ndarray | slice = slice(None)) -> ViewTracks:
    """The view's given frames and track columns."""
    return ViewTracks(v.name, v.camera, v.times_ref[frames], v.period, v.track_ids[cols],
                      v.xy_tkl2[frames][:, cols], v.vis_tkl[frames][:, cols], v.valid_tk[frames][:, cols],
                      v.height_tk[frames][:, cols])


@dataclass
class ViewSource:
    """A view's whole-take index and its frames on request (see module doc).

    times_ref (T,), track_ids (K,); valid_tk (T, K) and centroid_tk2 (T, K, 2) become those of the
    built frames as windows are read (``window`` records them: the first pass over the take's
    windows fills them). ``read_rows(start, stop, track_ids)``: frames start:stop with the given
    tracks (None: at least those present in them)."""

    name: str
    camera: Camera
    times_ref: np.ndarray
    period: float
    track_ids: np.ndarray
    valid_tk: np.ndarray
    centroid_tk2: np.ndarray
    read_rows: Callable[[int, int, np.ndarray | None], ViewTracks]

    @property
    def n_tracks(self) -> int:
        return len(self.track_ids)

    @classmethod
    def in_memory(cls, v: ViewTracks) -> "ViewSource":
        def read(a: int, b: int, ids: np.ndarray | None) -> ViewTracks:
            return take(v, slice(a, b), slice(None) if ids is None else np.flatnonzero(np.isin(v.track_ids, ids)))

        return cls(v.name, v.camera, v.times_ref, v.period, v.track_ids, v.valid_tk.copy(),
                   np.full((*v.valid_tk.shape, 2), np.nan), read)

    @classmethod
    def from_file(cls, tf, camera: Camera, times_ref: np.ndarray, vis_threshold: float = 0.5,
                  min_height_px: float = 8.0) -> "ViewSource":
        """A landmark or keypoint file (core.trackrows.TrackFile: xy, valid, visibility per frame) streamed."""
        times_ref = np.asarray(times_ref, np.float64)
        period = float(np.median(np.diff(times_ref))) if len(times_ref) > 1 else 1.0
        name, track_ids = str(tf.header["camera"]), tf.track_ids

        def read(a: int, b: int, ids: np.ndarray | None) -> ViewTracks:
            cols = tf.columns_in(a, b) if ids is None else np.flatnonzero(np.isin(track_ids, ids))
            w = tf.window(a, b, keys=("valid", "xy", "visibility"), cols=cols)
            return ViewTracks.from_arrays(name, w.track_ids, w.xy, w.valid, w.visibility, camera,
                                          times_ref[a:b], vis_threshold, min_height_px, period=period)

        valid = tf.valid_tk()
        return cls(name, camera, times_ref, period, track_ids, valid, np.full((*valid.shape, 2), np.nan), read)

    @property
    def _order(self) -> np.ndarray:
        """The track columns sorted by id (to find a window's tracks among them)."""
        if getattr(self, "_order_cache", None) is None:
            self._order_cache = np.argsort(self.track_ids, kind="stable")
        return self._order_cache

    def window(self, lo: float, hi: float, track_ids: np.ndarray | None = None) -> ViewTracks | None:
        """The frames with lo <= t < hi and the tracks present in them, or the given tracks (a
        keypoint view read like its landmark view: matching pairs them column by column); None if
        none."""
        f = np.flatnonzero((self.times_ref >= lo) & (self.times_ref < hi))
        if not len(f):
            return None
        v = self.read_rows(int(f[0]), int(f[-1]) + 1, track_ids)
        if len(f) != f[-1] - f[0] + 1:  # times out of order: only the frames in the window
            v = take(v, f - f[0])
        cols = np.searchsorted(self.track_ids, v.track_ids, sorter=self._order)
        cols = self._order[np.minimum(cols, len(self._order) - 1)]
        valid, cent = np.zeros((len(f), self.n_tracks), bool), np.full((len(f), self.n_tracks, 2), np.nan)
        valid[:, cols], cent[:, cols] = v.valid_tk, centroids(v)
        self.valid_tk[f], self.centroid_tk2[f] = valid, cent
        keep = np.flatnonzero(v.valid_tk.any(0) if track_ids is None else np.isin(v.track_ids, track_ids))
        if not len(keep):
            return None
        return take(v, slice(None), keep)
