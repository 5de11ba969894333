"""The network's per-frame probabilities, denoised where the truth is coherent.

A person's contact with another person and a landmark's visibility change slowly against the
frame rate, and contact covers patches of skin, not single landmarks; MammaNet predicts each crop
on its own, so its probabilities flicker from frame to frame and landmark to landmark. Averaging
over a track's neighbouring frames (a Gaussian in time, in seconds, so 30 and 60 fps footage are
smoothed alike) and, for contact, over each landmark's nearest neighbours on the body removes
that flicker. On the demo's workspace (`mamma-kit demo`, builtin tracker): person-contact ROC AUC
0.845 -> 0.856, visibility accuracy 86.7 -> 87.3 % (benchmarks/landmarks_smoothing.py).

- ``smooth_over_time(p_tkl, valid_tk, times_t, sigma_s)``: (T, K, L) probabilities averaged
  over each track's valid frames within 3 sigma.
- ``landmark_neighbours(points_l3, k)``: (L, k) the k nearest landmarks (itself first).
- ``smooth_probabilities(lt, sigma_s, neighbours_lk)``: a LandmarkTracks' contact and visibility
  smoothed (floor contact is left alone: the network's is already at an AUC of 0.99).
- ``smooth_landmarks(lt, sigma_s)``: what the landmarks stage writes: the above with the
  CONTACT_NEIGHBOURS nearest landmarks of the open body when the landmarks are its set (time only
  for another set).
- ``RowSmoother``: the same for rows that arrive in frame order (the stage streams a take of
  minutes into its file): a row goes out once every frame within reach of it is in, smoothed to
  the bit as ``smooth_landmarks`` smooths the whole take.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from mamma_kit.core.tracks import LandmarkTracks

SMOOTH_S = 0.1  # s: the Gaussian's sigma in time (3 frames at 30 fps)
CONTACT_NEIGHBOURS = 4  # landmarks (itself included) a contact probability is averaged over


def reach_frames(times_t: np.ndarray, sigma_s: float) -> int:
    """Neighbouring frames within 3 sigma_s of a frame, at the take's median frame step."""
    dt = float(np.median(np.diff(times_t))) if len(times_t) > 1 else 1.0
    return int(np.ceil(3 * sigma_s / max(dt, 1e-9)))


def smooth_over_time(p_tkl: np.ndarray, valid_tk: np.ndarray, times_t: np.ndarray, sigma_s: float,
                     reach: int | None = None) -> np.ndarray:
    """(T, K, L) -> (T, K, L): each valid entry the Gaussian-weighted mean of its track's valid
    frames within 3 sigma_s seconds (frame times may be irregular); invalid entries unchanged.
    ``reach``: the frames looked at either side (default: reach_frames of these times)."""
    T = len(times_t)
    if sigma_s <= 0 or T < 2:
        return p_tkl.copy()
    reach = reach_frames(times_t, sigma_s) if reach is None else reach
    p = np.where(valid_tk[..., None], p_tkl, 0.0).astype(np.float64)
    acc = np.zeros_like(p)
    wsum = np.zeros(p.shape[:2])
    idx = np.arange(T)
    for o in range(-reach, reach + 1):
        j = np.clip(idx + o, 0, T - 1)
        inside = (idx + o >= 0) & (idx + o < T)
        w_t = np.exp(-0.5 * ((times_t[j] - times_t) / sigma_s) ** 2) * inside  # (T,)
        w_tk = w_t[:, None] * valid_tk[j]  # (T, K)
        acc += w_tk[..., None] * p[j]
        wsum += w_tk
    out = acc / np.maximum(wsum, 1e-12)[..., None]
    return np.where(valid_tk[..., None], out, p_tkl).astype(p_tkl.dtype)


def landmark_neighbours(points_l3: np.ndarray, k: int) -> np.ndarray:
    """(L, 3) landmark positions on the rest body -> (L, k) indices of the k nearest (itself first)."""
    from scipy.spatial import cKDTree

    _, nn = cKDTree(points_l3).query(points_l3, k=k)
    return np.asarray(nn).reshape(len(points_l3), k)


def smooth_probabilities(lt: LandmarkTracks, sigma_s: float, neighbours_lk: np.ndarray | None,
                         reach: int | None = None) -> LandmarkTracks:
    """A copy of ``lt`` with contact smoothed over time and over ``neighbours_lk`` (None: time
    only) and visibility over time (``reach``: see smooth_over_time)."""
    contact = smooth_over_time(lt.contact, lt.valid, lt.frame_times, sigma_s, reach)
    if neighbours_lk is not None:
        contact = contact[..., neighbours_lk].mean(-1)
    visibility = smooth_over_time(lt.visibility, lt.valid, lt.frame_times, sigma_s, reach)
    return dataclasses.replace(lt, contact=contact.astype(lt.contact.dtype),
                               visibility=visibility.astype(lt.visibility.dtype))


def contact_neighbours(landmark_set: str, n_landmarks: int) -> np.ndarray | None:
    """(L, CONTACT_NEIGHBOURS) the nearest landmarks on the open body when the landmarks are its set, else None."""
    from mamma_kit.body.model import load_body_model

    body = load_body_model("open")
    if landmark_set == f"{body.name}:{body.landmarks.source}" and n_landmarks == len(body.landmark_ids):
        return landmark_neighbours(body.np.v_template[body.landmark_ids], CONTACT_NEIGHBOURS)
    return None


def smooth_landmarks(lt: LandmarkTracks, sigma_s: float = SMOOTH_S) -> LandmarkTracks:
    """The landmarks stage's smoothing (module doc); sigma_s <= 0 returns ``lt`` unchanged."""
    if sigma_s <= 0:
        return lt
    return smooth_probabilities(lt, sigma_s, contact_neighbours(lt.landmark_set, lt.n_landmarks))


class RowSmoother:
    """``smooth_landmarks`` for rows that come in frame order (see module doc).

    >>> sm = RowSmoother(frame_times, SMOOTH_S, neighbours)
    >>> for frame_n, track_n, cells in batches:            # rows sorted by (frame, track)
    ...     out = sm.push(frame_n, track_n, cells, complete_before=next_frame)  # rows now final
    >>> out = sm.finish()                                   # the rest

    ``cells``: the rows' visibility and contact (n, L), with any other fields, which pass through.
    ``complete_before``: every row of the frames before it has been pushed."""

    def __init__(self, frame_times: np.ndarray, sigma_s: float, neighbours_lk: np.ndarray | None):
        self.times = np.asarray(frame_times, np.float64)
        self.sigma_s, self.neighbours = float(sigma_s), neighbours_lk
        self.reach = reach_frames(self.times, self.sigma_s)
        self._frame = np.zeros(0, np.int64)
        self._track = np.zeros(0, np.int64)
        self._cells: dict[str, np.ndarray] = {}
        self._sent = 0  # rows of the buffer already given out (they stay while others need them)

    def push(self, frame_n, track_n, cells: dict, complete_before: int):
        self._frame = np.r_[self._frame, np.asarray(frame_n, np.int64)]
        self._track = np.r_[self._track, np.asarray(track_n, np.int64)]
        self._cells = {k: np.concatenate([self._cells[k], v]) if k in self._cells else np.asarray(v)
                       for k, v in cells.items()}
        return self._emit(int(complete_before) - self.reach)

    def finish(self):
        return self._emit(len(self.times))

    def _emit(self, ready_before: int):
        """Rows of frames < ready_before smoothed and given out; rows no longer needed dropped."""
        n_ready = int(np.searchsorted(self._frame, ready_before))
        if n_ready <= self._sent:
            return self._frame[:0], self._track[:0], {k: v[:0] for k, v in self._cells.items()}
        lo, hi = self._sent, n_ready
        f0 = int(self._frame[lo]) - self.reach  # the context: every buffered row within reach
        use = self._frame >= f0
        out = self._smooth(use, np.arange(lo, hi))
        self._sent = hi
        keep_from = int(np.searchsorted(self._frame, int(self._frame[hi - 1]) + 1 - self.reach))
        keep_from = min(keep_from, self._sent)
        self._frame, self._track = self._frame[keep_from:], self._track[keep_from:]
        self._cells = {k: v[keep_from:] for k, v in self._cells.items()}
        self._sent -= keep_from
        return out

    def _smooth(self, use: np.ndarray, rows: np.ndarray):
        """The given buffer rows smoothed over the buffer rows ``use`` (a dense grid of their frames and tracks)."""
        f_n, k_n = self._frame[use], self._track[use]
        first = int(f_n.min())
        tracks, k_c = np.unique(k_n, return_inverse=True)
        F = int(f_n.max()) - first + 1
        valid = np.zeros((F, len(tracks)), bool)
        valid[f_n - first, k_c] = True
        times = self.times[first:first + F]
        pos = np.flatnonzero(use)
        where = np.searchsorted(pos, rows)  # each given row's place among the used ones
        out = {k: v[rows].copy() for k, v in self._cells.items()}
        for name in ("visibility", "contact"):
            grid = np.zeros((F, len(tracks), self._cells[name].shape[-1]), self._cells[name].dtype)
            grid[f_n - first, k_c] = self._cells[name][use]
            sm = smooth_over_time(grid, valid, times, self.sigma_s, self.reach)[f_n[where] - first, k_c[where]]
            if name == "contact" and self.neighbours is not None:
                sm = sm[..., self.neighbours].mean(-1)
            out[name] = sm.astype(self._cells[name].dtype)
        return self._frame[rows], self._track[rows], out
