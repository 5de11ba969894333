"""Motion sync: camera clocks from the people's movement, for videos without a usable clap or LTC.

Inputs: BlazePose keypoints per camera (keypoints/<cam>.npz, on each camera's own frame times) and
the calibrated rig. For each camera against the reference:
1. coarse offset: every whole-frame lag up to ``max_lag_s`` (and the lag where the two views'
   motion signals correlate best: every tracked person's limb-joint speed in box heights per
   second, summed), with the two views' tracks paired at that lag by their epipolar distance
   (Hungarian); the lag pairing the most people at the lowest residual wins (on short takes the
   speed correlation alone was off by hundreds of ms on the real recording);
2. the tracks paired at the coarse offset;
3. sub-frame offset: the offset that minimises the paired keypoints' robust symmetric epipolar
   distance (in box heights), the other view's keypoints interpolated at each frame's own
   timestamp (variable frame rate); a scan at a tenth of a frame, then a bounded 1-D minimisation;
4. joint refinement: all cameras' offsets at once by robust Gauss-Newton on every pair's signed
   epipolar distances (the derivative from the other view's points half a frame either side, so
   its own noise pulls neither way), each pair's tracks paired again at step 3's joint solve,
   started there and kept within LOOP_TOLERANCE_FRAMES of it. One pair's capped-distance minimum
   is flat and noisy on real footage (the real recording: 9-12 ms off); the pairs together pull
   it to 0.6-3.6 ms;
5. drift: on takes of DRIFT_MIN_TAKE_S or more, step 3 in windows of DRIFT_WINDOW_S (split at gaps
   in the timestamps too), a weighted line through the windows' offsets per camera pair, and every
   camera's rate and offset from all pairs jointly, like the offsets.
Confidence per camera: how much deeper the minimum is than the residual 0.1 s away.
Frames further apart than GAP_PERIODS frame periods (a pause in recording, or a capture rendered
in windows) are never interpolated across.
"""

from __future__ import annotations

import warnings
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment, minimize_scalar

from mamma_kit.core.camera import Camera, Rig
from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError
from mamma_kit.core.tracks import KeypointTracks

# the limb joints (shoulders, elbows, wrists, hips, knees, ankles) that carry the motion
LIMBS = np.r_[11:17, 23:29]
MIN_VISIBILITY = 0.5
# an epipolar distance is capped at this many box heights: a wrong point cannot outweigh the rest
CAP = 0.15
# a camera pair needs at least this many shared (frame, joint) observations
MIN_OBSERVATIONS = 200
# tracks are paired across views only below this median epipolar distance (box heights)
MAX_PAIR_DISTANCE = 0.06
# the minimum must be at least this much deeper than CONTRAST_S away, else the motion does not
# determine the offset (one frame at 60 fps moves the residual by only 1-4 % on the real recording:
# keypoint noise and calibration error dominate it)
MIN_CONTRAST = 0.05
CONTRAST_S = 0.1
# drift is estimated on takes of at least this length, in windows of this length
DRIFT_MIN_TAKE_S = 40.0
# a camera below this confidence gets a warning: on held-out renders every camera that motion sync
# placed tens of ms or more off had 0.13-0.44, those within a few ms 0.25-1.0
WARN_CONFIDENCE = 0.5
# in the joint solve, a camera pair whose offset disagrees with the others by more than this many
# frames is dropped
LOOP_TOLERANCE_FRAMES = 1.0
DRIFT_WINDOW_S = 15.0
# a drift window needs at least this much of the take
DRIFT_MIN_WINDOW_S = 2.0
GAP_PERIODS = 2.5


@contextmanager
def warnings_off():
    """NaN-aware reductions over frames where a track is absent warn on every all-NaN slice."""
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


@dataclass
class View:
    """One camera's keypoints, undistorted, with per-(frame, track) box heights."""

    cam: Camera
    times: np.ndarray  # (T,) own clock
    xy: np.ndarray  # (T, K, J, 2) undistorted px, NaN where not seen
    height: np.ndarray  # (T, K) px

    @classmethod
    def of(cls, cam: Camera, kt: KeypointTracks) -> "View":
        return cls.from_points(cam, kt.frame_times, kt.xy, kt.visibility, kt.valid)

    @classmethod
    def from_points(cls, cam: Camera, times_t: np.ndarray, xy_tkj2: np.ndarray, vis_tkj: np.ndarray,
                    valid_tk: np.ndarray) -> "View":
        """From BlazePose's 33 points per frame and track (or person): px, visibility, presence."""
        xy = xy_tkj2[:, :, LIMBS].astype(np.float64)
        seen = valid_tk[..., None] & (vis_tkj[:, :, LIMBS] > MIN_VISIBILITY)
        und = cam.undistort_pixels(np.nan_to_num(xy).reshape(-1, 2)).reshape(xy.shape)
        und = np.where(seen[..., None], und, np.nan)
        allxy = np.where(valid_tk[..., None, None], xy_tkj2, np.nan)
        with np.errstate(invalid="ignore"):
            h = np.nanmax(allxy[..., 1], axis=2) - np.nanmin(allxy[..., 1], axis=2)
        return cls(cam, np.asarray(times_t, np.float64), und, np.where(valid_tk, h, np.nan))

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Keypoints and heights linearly interpolated at own-clock times t (N,): (N, K, J, 2), (N, K)."""
        i1 = np.clip(np.searchsorted(self.times, t), 1, len(self.times) - 1)
        i0 = i1 - 1
        step = self.times[i1] - self.times[i0]
        w = ((t - self.times[i0]) / np.maximum(step, 1e-9))
        inside = (t >= self.times[0]) & (t <= self.times[-1]) & (step <= GAP_PERIODS * self.period)
        xy = (1 - w)[:, None, None, None] * self.xy[i0] + w[:, None, None, None] * self.xy[i1]
        h = (1 - w)[:, None] * self.height[i0] + w[:, None] * self.height[i1]
        xy[~inside] = np.nan
        return xy, h

    @property
    def period(self) -> float:
        return float(np.median(np.diff(self.times))) if len(self.times) > 1 else 1.0

    def motion(self) -> np.ndarray:
        """(T,) summed limb-joint speed in box heights per second (0 where nothing is tracked)."""
        dt = np.diff(self.times)[:, None, None]
        dt = np.where(dt <= GAP_PERIODS * self.period, dt, np.nan)  # no speed across a gap
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.linalg.norm(np.diff(self.xy, axis=0), axis=-1) / dt / self.height[1:, :, None]  # (T-1, K, J)
            per_track = np.nanmedian(np.where(np.isfinite(v), v, np.nan), axis=2) if v.shape[1] else \
                np.zeros((len(dt), 0))
        s = np.nansum(per_track, axis=1)
        return np.r_[s[:1], s] if len(s) else np.zeros(len(self.times))


def _epipolar(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Symmetric epipolar distance (px) of undistorted points xa (..., 2) in a and xb in b, F: a -> b."""
    ha = np.concatenate([xa, np.ones_like(xa[..., :1])], -1)
    hb = np.concatenate([xb, np.ones_like(xb[..., :1])], -1)
    lb = ha @ F.T  # lines in b
    la = hb @ F  # lines in a
    num = np.abs((hb * lb).sum(-1))
    return 0.5 * (num / np.hypot(lb[..., 0], lb[..., 1]) + num / np.hypot(la[..., 0], la[..., 1]))


def signed_epipolar(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Signed distance (px) of undistorted points xb (..., 2) in b to the epipolar lines of xa in a."""
    ha = np.concatenate([xa, np.ones_like(xa[..., :1])], -1)
    hb = np.concatenate([xb, np.ones_like(xb[..., :1])], -1)
    lb = ha @ F.T
    return (hb * lb).sum(-1) / np.hypot(lb[..., 0], lb[..., 1])


def signed_series(a: View, b: View, F: np.ndarray, pairs, offset: float, frames: np.ndarray | None = None
                  ) -> np.ndarray:
    """(N, S) signed distances in box heights of the paired tracks' joints (S = pairs x joints) at
    a's frames (all, or ``frames``), b interpolated at ``offset``; NaN where unseen."""
    idx = np.arange(len(a.times)) if frames is None else frames
    xb, hb = b.at(a.times[idx] - offset)
    cols = [signed_epipolar(F, a.xy[idx, i], xb[:, j]) / np.sqrt(a.height[idx, i, None] * hb[:, j, None])
            for i, j in pairs]
    return np.concatenate(cols, 1) if cols else np.zeros((len(idx), 0))


def normal_equations(a: View, b: View, F: np.ndarray, pairs, offset: float, frames: np.ndarray | None = None
                     ) -> tuple[float, float, int]:
    """One pair's Gauss-Newton terms at ``offset`` (on a's ``frames``, default all): (sum r^2,
    sum r s, observations) over the distances s within 3 robust spreads of their median,
    r = ds/doffset from b's points half a frame either side, both in units of the spread."""
    T = b.period
    s0 = signed_series(a, b, F, pairs, offset, frames).ravel()
    r = ((signed_series(a, b, F, pairs, offset + 0.5 * T, frames) -
          signed_series(a, b, F, pairs, offset - 0.5 * T, frames)) / T).ravel()
    ok = np.isfinite(s0) & np.isfinite(r)
    if ok.sum() < MIN_OBSERVATIONS:
        return 0.0, 0.0, 0
    med = np.median(s0[ok])
    sig = max(1.4826 * float(np.median(np.abs(s0[ok] - med))), 1e-6)
    w = ok & (np.abs(s0 - med) < 3 * sig)
    return float(np.sum(r[w] ** 2)) / sig ** 2, float(np.sum(r[w] * s0[w])) / sig ** 2, int(w.sum())


def all_track_pairs(views: dict[str, View], names: list[str], offsets: np.ndarray) -> dict[tuple[str, str], list]:
    """Every camera pair's tracks paired at ``offsets``: a pair whose own minimum was off (and so was
    dropped from the joint solve, or weighed little) still carries its share of the motion."""
    out = {}
    for i, a in enumerate(names):
        for j in range(i + 1, len(names)):
            b = names[j]
            tp = pair_tracks(views[a], views[b], views[a].cam.fundamental_to(views[b].cam), offsets[j] - offsets[i])
            if tp:
                out[(a, b)] = tp
    return out


def refine_jointly(views: dict[str, View], names: list[str], reference: str, offsets: np.ndarray,
                   track_pairs: dict[tuple[str, str], list], iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Every camera's offset (t_ref = t_cam + o) by Gauss-Newton on all pairs' signed distances at
    once (module docstring, step 4), from ``offsets``; a camera that would move more than
    LOOP_TOLERANCE_FRAMES keeps its start. -> (offsets, their standard deviations if the errors were
    independent, s; the start and NaN when the pairs do not tie every camera to the reference)."""
    C, ref = len(names), names.index(reference)
    free = [k for k in range(C) if k != ref]
    period = min(v.period for v in views.values())
    terms = [(names.index(a), names.index(b), views[a], views[b], views[a].cam.fundamental_to(views[b].cam), tp)
             for (a, b), tp in track_pairs.items()]
    off = offsets.copy()
    for _ in range(iterations):
        H, g = np.zeros((C, C)), np.zeros(C)
        for i, j, va, vb, F, pairs in terms:
            h, q, n = normal_equations(va, vb, F, pairs, off[j] - off[i])
            if n == 0:
                continue
            e = np.zeros(C)
            e[i], e[j] = -1.0, 1.0
            H += h * np.outer(e, e)
            g += q * e
        Hf = H[np.ix_(free, free)]
        if np.linalg.matrix_rank(Hf) < len(free):
            return offsets, np.full(C, np.nan)
        step = np.zeros(C)
        step[free] = np.clip(-np.linalg.solve(Hf, g[free]), -0.5 * period, 0.5 * period)
        off += step
        if np.abs(step).max() < 1e-4 * period:
            break
    far = np.abs(off - offsets) > LOOP_TOLERANCE_FRAMES * period
    off[far] = offsets[far]
    sd = np.zeros(C)
    sd[free] = np.sqrt(np.diag(np.linalg.inv(Hf)))
    return off, sd


def coarse_offset(a: View, b: View, max_lag_s: float) -> float:
    """Offset o (t_ref = t_b + o) maximising the correlation of the two motion signals."""
    dt = 0.5 * min(np.median(np.diff(a.times)), np.median(np.diff(b.times)))
    grid_a = np.arange(a.times[0], a.times[-1], dt)
    sa = np.interp(grid_a, a.times, a.motion())
    sb_t = b.motion()
    # lags up to a third of the shorter take: the signals must overlap over most of it to compare
    take = min(a.times[-1] - a.times[0], b.times[-1] - b.times[0])
    max_lag_s = min(max_lag_s, take / 3)
    lags = np.arange(-max_lag_s, max_lag_s + dt / 2, dt)
    best, best_o = -np.inf, 0.0
    za = (sa - sa.mean()) / (sa.std() + 1e-12)
    for o in lags:
        tb = grid_a - o
        ok = (tb >= b.times[0]) & (tb <= b.times[-1])
        if ok.sum() < 0.6 * len(grid_a):
            continue
        sb = np.interp(tb[ok], b.times, sb_t)
        zb = (sb - sb.mean()) / (sb.std() + 1e-12)
        r = float(np.mean(za[ok] * zb))
        if r > best:
            best, best_o = r, float(o)
    return best_o


def pair_tracks(a: View, b: View, F: np.ndarray, offset: float) -> list[tuple[int, int]]:
    """Tracks of a and b that show the same person: Hungarian on the mean capped epipolar distance."""
    xb, hb = b.at(a.times - offset)
    Ka, Kb = a.xy.shape[1], b.xy.shape[1]
    cost = np.full((Ka, Kb), np.inf)
    for i in range(Ka):
        for j in range(Kb):
            d = _epipolar(F, a.xy[:, i], xb[:, j]) / np.sqrt(a.height[:, i, None] * hb[:, j, None])
            d = d[np.isfinite(d)]
            if len(d) >= 20:
                cost[i, j] = np.median(d)
    if not np.isfinite(cost).any():
        return []
    r, c = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e3))
    return [(int(i), int(j)) for i, j in zip(r, c) if cost[i, j] < MAX_PAIR_DISTANCE]


def residual(a: View, b: View, F: np.ndarray, pairs, offset: float, frames: np.ndarray | None = None
             ) -> tuple[float, int]:
    """Mean capped symmetric epipolar distance (box heights) of the paired tracks at ``offset``."""
    idx = np.arange(len(a.times)) if frames is None else frames
    xb, hb = b.at(a.times[idx] - offset)
    ds = []
    for i, j in pairs:
        d = _epipolar(F, a.xy[idx, i], xb[:, j]) / np.sqrt(a.height[idx, i, None] * hb[:, j, None])
        ds.append(d[np.isfinite(d)])
    d = np.concatenate(ds) if ds else np.zeros(0)
    return (float(np.minimum(d, CAP).mean()) if len(d) else np.inf), int(len(d))


def fine_offset(a: View, b: View, F, pairs, start: float, frames=None) -> tuple[float, dict]:
    """Sub-frame offset near ``start`` minimising the paired epipolar residual."""
    period = float(np.median(np.diff(b.times)))
    scan = start + np.arange(-2.0, 2.0 + 1e-9, 0.1) * period
    vals = np.array([residual(a, b, F, pairs, o, frames)[0] for o in scan])
    k = int(np.argmin(vals))
    lo, hi = scan[max(k - 1, 0)], scan[min(k + 1, len(scan) - 1)]
    res = minimize_scalar(lambda o: residual(a, b, F, pairs, o, frames)[0], bounds=(lo, hi), method="bounded",
                          options={"xatol": 1e-5 * period})
    o = float(res.x)
    best, n = residual(a, b, F, pairs, o, frames)
    far = min(residual(a, b, F, pairs, o - CONTRAST_S, frames)[0], residual(a, b, F, pairs, o + CONTRAST_S, frames)[0])
    contrast = float((far - best) / far) if np.isfinite(far) and far > 0 else 0.0
    return o, {"residual": best, "observations": n, "contrast": contrast, "scan_min": float(scan[k])}


def scan_offset(a: View, b: View, F: np.ndarray, max_lag_s: float, speed_lag: float) -> tuple[float, list]:
    """Coarse offset: every whole-frame lag up to ``max_lag_s`` (and the speed correlation's
    ``speed_lag``), tracks paired at each, the lowest paired epipolar residual wins."""
    period = float(np.median(np.diff(b.times)))
    take = min(a.times[-1] - a.times[0], b.times[-1] - b.times[0])
    lim = min(max_lag_s, take / 3)
    cands = np.r_[np.arange(-lim, lim + 1e-9, period), speed_lag]
    best = (np.inf, 0.0, [])
    for o in cands:
        pairs = pair_tracks(a, b, F, o)
        r, n = residual(a, b, F, pairs, o) if pairs else (np.inf, 0)
        # a lag that pairs fewer people explains less: compare residuals only at the most pairs
        key = (-len(pairs), r)
        if best[2] == [] or key < (-len(best[2]), best[0]):
            best = (r, float(o), pairs)
    return best[1], best[2]


def pair_offset(a: View, b: View, max_lag_s: float) -> tuple[float, float, dict]:
    """One camera pair: (offset of b relative to a, confidence, diagnostics); confidence 0 where the
    pair shares no person or too little motion."""
    F = a.cam.fundamental_to(b.cam)
    coarse, pairs = scan_offset(a, b, F, max_lag_s, coarse_offset(a, b, max_lag_s))
    if not pairs:
        return coarse, 0.0, {"track_pairs": [], "observations": 0, "contrast": 0.0}
    o, info = fine_offset(a, b, F, pairs, coarse)
    ok = info["observations"] >= MIN_OBSERVATIONS and info["contrast"] >= MIN_CONTRAST
    conf = float(np.clip(info["contrast"] / 0.5, 0.0, 1.0)) * min(1.0, len(pairs) / max(a.xy.shape[1], 1)) if ok else 0.0
    return o, conf, {"coarse_offset_ms": round(coarse * 1e3, 3), "track_pairs": pairs,
                     "residual_box_heights": round(info["residual"], 5), "observations": info["observations"],
                     "contrast": round(info["contrast"], 4)}


def drift_windows(times: np.ndarray) -> list[np.ndarray]:
    """Frame indices of the windows drift is measured in: runs without gaps, cut into pieces of
    about DRIFT_WINDOW_S, each at least DRIFT_MIN_WINDOW_S long."""
    period = float(np.median(np.diff(times)))
    runs = np.split(np.arange(len(times)), np.flatnonzero(np.diff(times) > GAP_PERIODS * period) + 1)
    out = []
    for r in runs:
        span = times[r[-1]] - times[r[0]]
        if span < DRIFT_MIN_WINDOW_S:
            continue
        n = max(1, int(round(span / DRIFT_WINDOW_S)))
        out += [p for p in np.array_split(r, n) if times[p[-1]] - times[p[0]] >= DRIFT_MIN_WINDOW_S]
    return out


def pair_drift(a: View, b: View, pairs, offset: float) -> tuple[float, float, float, dict] | None:
    """Offset at t_a = 0 and rate of b against a (t_a = (1 + rate) t_b + offset) from the windows'
    sub-frame offsets, with the rate's standard error; None when fewer than two windows tie it."""
    from mamma_kit.timing.fit import robust_line

    F = a.cam.fundamental_to(b.cam)
    t_w, o_w, sd_w = [], [], []
    for idx in drift_windows(a.times):
        o, info = fine_offset(a, b, F, pairs, offset, idx)
        if info["observations"] < MIN_OBSERVATIONS // 2 or info["contrast"] < MIN_CONTRAST:
            continue
        t_w.append(float(a.times[idx].mean()))
        o_w.append(o)
        sd_w.append(1.0 / np.sqrt(info["observations"]))  # relative weight: more observations, steadier
    if len(t_w) < 2 or np.ptp(t_w) < DRIFT_MIN_TAKE_S / 2:
        return None
    t_w, o_w = np.array(t_w), np.array(o_w)
    fit = robust_line(t_w, o_w, 1.0 / np.square(sd_w), scale_floor=2e-4)
    s, o0 = fit.slope, fit.intercept  # t_a = t_b + o0 + s t_a
    sd = fit.slope_sd if np.isfinite(fit.slope_sd) and len(t_w) > 2 else 2e-4 * np.sqrt(2) / np.ptp(t_w)
    diag = {"windows_s": [round(float(t), 3) for t in t_w], "window_offsets_ms": [round(float(o) * 1e3, 4) for o in o_w]}
    return o0 / (1 - s), 1 / (1 - s) - 1, float(max(sd, 1e-7)), diag


def _linked(rows: list[np.ndarray], names: list[str], reference: str) -> set[str]:
    """Cameras tied to the reference through the pairs in ``rows`` (each row: -1 at a, +1 at b)."""
    linked, grew = {reference}, True
    while grew:
        grew = False
        for r in rows:
            a, b = names[int(np.flatnonzero(r < 0)[0])], names[int(np.flatnonzero(r > 0)[0])]
            if (a in linked) != (b in linked):
                linked |= {a, b}
                grew = True
    return linked


def _connected(rows, names, reference) -> bool:
    return len(_linked(rows, names, reference)) == len(names)


def motion_clocks(kts: dict[str, KeypointTracks], rig: Rig, reference: str, max_lag_s: float = 2.0
                  ) -> tuple[dict[str, ClockModel], dict, list[str]]:
    """Every camera's clock relative to ``reference`` from the people's motion (module docstring):
    every camera pair's offset, then all cameras' offsets jointly by weighted least squares over the
    pairs (o_b - o_a = o_ab), so a camera that sees the reference's people badly (occlusion) is tied
    in through the others. Drift is not estimated on takes shorter than DRIFT_MIN_TAKE_S.
    -> (clocks, per-camera diagnostics, warnings)."""
    with warnings_off():
        return _motion_clocks(kts, rig, reference, max_lag_s)


def _motion_clocks(kts, rig, reference, max_lag_s):
    names = list(kts)
    empty = [n for n, kt in kts.items() if not (kt.valid.any() if kt.valid.size else False)]
    if empty:
        raise UserError(f"motion sync: no people tracked in {', '.join(empty)} (their keypoints files are empty)",
                        "motion sync needs people moving in view of every camera: check `mamma-kit track` found "
                        "them (report/, or --people N), or sync by clap, LTC, timecode, flash or --method synced")
    views = {n: View.of(rig[n], kt) for n, kt in kts.items()}
    rows, rhs, wts, pair_diag = [], [], [], {}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            o, conf, d = pair_offset(views[a], views[b], max_lag_s)
            pair_diag[(a, b)] = {"offset_ms": round(o * 1e3, 3), "confidence": round(conf, 3), **d}
            if conf > 0:
                r = np.zeros(len(names))
                r[names.index(a)], r[names.index(b)] = -1.0, 1.0
                rows.append(r)
                rhs.append(o)
                wts.append(conf)
    # every camera must be tied to the reference through pairs that saw the same people move
    period = min(float(np.median(np.diff(v.times))) for v in views.values())
    lost = [n for n in names if n not in _linked(rows, names, reference)]
    if lost:
        why = "; ".join(f"{a}-{b}: {d['observations']} shared observations, contrast {d['contrast']:.0%}"
                        for (a, b), d in pair_diag.items() if lost[0] in (a, b))
        raise UserError(f"motion sync: too little shared motion to tie {', '.join(lost)} to the other cameras ({why})",
                        "film the people moving in view of every camera (a jump, arms swung), or sync by clap, LTC "
                        "or timecode")
    ref_i = names.index(reference)
    cols = [k for k in range(len(names)) if k != ref_i]
    used = list(range(len(rows)))
    while True:
        A, b = np.array([rows[i] for i in used]), np.array([rhs[i] for i in used])
        w = np.sqrt(np.array([wts[i] for i in used]))[:, None]
        x, *_ = np.linalg.lstsq(A[:, cols] * w, b * w[:, 0], rcond=None)
        offsets = np.zeros(len(names))
        offsets[cols] = x
        resid = A @ offsets - b
        worst = int(np.argmax(np.abs(resid)))
        # a pair that disagrees with the others by more than a frame is dropped (one view's keypoints
        # can follow the wrong person through an occlusion), while the rest still tie every camera in
        trial = [u for k, u in enumerate(used) if k != worst]
        if abs(resid[worst]) <= LOOP_TOLERANCE_FRAMES * period or len(trial) < len(names) - 1 or \
                not _connected([rows[i] for i in trial], names, reference):
            break
        used = trial
    rows, wts = [rows[i] for i in used], [wts[i] for i in used]
    start = offsets.copy()
    offsets, sd = refine_jointly(views, names, reference, offsets, all_track_pairs(views, names, start))
    clocks, diag = {}, {}
    for k, n in enumerate(names):
        mine = [i for i, r in enumerate(rows) if r[k] != 0]
        conf = 1.0 if n == reference else float(np.clip(sum(wts[i] for i in mine), 0.0, 1.0))
        clocks[n] = ClockModel(float(offsets[k]), 0.0, "motion", conf)
        diag[n] = {"pairs": {f"{a}-{b}": d for (a, b), d in pair_diag.items() if n in (a, b)},
                   "loop_residual_ms": round(float(np.sqrt(np.mean(resid[mine] ** 2))) * 1e3, 3) if mine else None,
                   "pairs_solve_ms": round(float(start[k]) * 1e3, 3),
                   "joint_refinement_ms": round(float(offsets[k] - start[k]) * 1e3, 3),
                   "offset_sd_independent_errors_ms": round(float(sd[k]) * 1e3, 3) if np.isfinite(sd[k]) else None}
    notes = []
    weak = {n: c.confidence for n, c in clocks.items() if c.confidence < WARN_CONFIDENCE}
    if weak:
        notes.append("motion sync: " + ", ".join(f"{n} (confidence {v:.2f})" for n, v in weak.items()) +
                     " barely determined by the people's motion: its offset may be frames off; check the "
                     "report's sync plots, or sync by clap, LTC, a flash or the rig's clock")
    take = min(v.times[-1] - v.times[0] for v in views.values())
    if take >= DRIFT_MIN_TAKE_S:
        rates = _joint_drift(names, views, reference, pair_diag, clocks, diag, notes)
        if rates is not None:
            for n, (o, r) in rates.items():
                clocks[n].offset, clocks[n].rate = float(o), float(r)
    return clocks, diag, notes


def _joint_drift(names, views, reference, pair_diag, clocks, diag, notes):
    """Every camera's (offset, rate) from the pairs' windowed drift fits, solved jointly like the
    offsets (rates add along a chain of pairs to first order); None when the windows do not tie
    every camera in."""
    rows, rhs_o, rhs_r, wts = [], [], [], []
    for (a, b), d in pair_diag.items():
        if d["confidence"] <= 0 or not d.get("track_pairs"):
            continue
        # the pair's offset as the joint solve kept it (a dropped pair disagreed with the others)
        o_ab = clocks[b].offset - clocks[a].offset
        if abs(o_ab - d["offset_ms"] * 1e-3) > LOOP_TOLERANCE_FRAMES * views[b].period:
            continue
        got = pair_drift(views[a], views[b], d["track_pairs"], o_ab)
        if got is None:
            continue
        o0, rate, sd, dd = got
        d["drift"] = {"offset_at_zero_ms": round(o0 * 1e3, 4), "rate_ppm": round(rate * 1e6, 3),
                      "rate_sd_ppm": round(sd * 1e6, 3), **dd}
        r = np.zeros(len(names))
        r[names.index(a)], r[names.index(b)] = -1.0, 1.0
        rows.append(r)
        rhs_o.append(o0)
        rhs_r.append(rate)
        wts.append(1.0 / sd ** 2)
    if not rows or not _connected(rows, names, reference):
        notes.append("motion sync: the take is long but its windows do not tie every camera's drift in; "
                     "offsets only (drift 0)")
        return None
    ref_i = names.index(reference)
    cols = [k for k in range(len(names)) if k != ref_i]
    A = np.array(rows)[:, cols] * np.sqrt(wts)[:, None]
    out = {}
    sol = [np.linalg.lstsq(A, np.array(v) * np.sqrt(wts), rcond=None)[0] for v in (rhs_o, rhs_r)]
    for k, n in enumerate(names):
        if k == ref_i:
            out[n] = (0.0, 0.0)
        else:
            j = cols.index(k)
            out[n] = (sol[0][j], sol[1][j])
        diag[n]["drift_pairs"] = int(sum(1 for r in rows if r[k] != 0))
    return out
