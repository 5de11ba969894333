"""Clap synchronisation: onsets -> matched events -> GCC-PHAT per camera pair -> joint clocks.

1. Candidate events: sharp onsets in each camera's audio (timing.onsets).
2. Matching: each camera's onsets are matched to the reference camera's by voting over
   onset-time differences (coarse offset), then refined with a line (offset + drift) and
   re-matched tightly. An event is a reference onset that another camera also heard.
3. For every event and every camera pair that heard it: GCC-PHAT between short windows
   around the two onsets (the direct sound: ``window_pre_ms`` before to ``window_post_ms``
   after the onset, so echoes and the reverberant tail are left out), sub-sample peak.
   Each gives an observation: camera i's time t_i and camera j's time t_j of the same sound.
4. All observations of all pairs solve jointly, by robust weighted least squares, for every
   camera's (offset, rate) relative to the reference camera:
       (1 + a_j) t_j + o_j - d_jk / c  =  (1 + a_i) t_i + o_i - d_ik / c
   where d_ck is the distance from clap k to camera c's microphone when known (sound-travel
   correction), else 0. Two or more events spread over the take give the drift; one event
   gives an offset with the rate held at 0.
5. Loop consistency: for every event and camera triple, lag_ij + lag_jl - lag_il should be 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations
from typing import Mapping

import numpy as np
from scipy import signal

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError
from mamma_kit.timing.fit import robust_line
from mamma_kit.timing.gcc import gcc_phat
from mamma_kit.timing.onsets import Onsets, detect_onsets, highpass

SPEED_OF_SOUND = 343.0


@dataclass
class ClapSettings:
    threshold_db: float = 8.0         # onset: rise above the preceding background
    min_separation_s: float = 0.25    # onsets closer than this are one event
    window_pre_ms: float = 1.0        # GCC window before the onset
    window_post_ms: float = 5.0       # ... and after it (the direct sound of a clap)
    max_lag_ms: float = 2.0           # GCC search range around the onset alignment
    beta: float = 1.0                 # PHAT exponent (1 = full whitening)
    band_hz: tuple[float, float] = (500.0, 8000.0)
    match_tolerance_s: float = 0.1    # coarse onset matching
    max_offset_s: float | None = None  # bound on |offset| between cameras (None: any)
    min_psr: float = 4.0              # GCC peaks weaker than this are ignored
    speed_of_sound: float = SPEED_OF_SOUND
    loop_tolerance_ms: float = 2.0    # loop closure beyond this is an error
    estimate_positions: bool = True   # with calibrated cameras and no clap positions: estimate them
    position_prior_m: float = 1.0     # spread of claps around the rig centre (prior of the estimate)

    @classmethod
    def from_dict(cls, d: Mapping | None) -> "ClapSettings":
        s = cls()
        for k, v in (d or {}).items():
            if hasattr(s, k):
                setattr(s, k, tuple(v) if isinstance(v, list) else v)
        return s


@dataclass
class Track:
    """One camera's audio for clap sync: mono samples on the camera's clock."""
    name: str
    x: np.ndarray      # (N,) float64
    sr: int
    start_s: float     # camera (container) time of sample 0
    channel: int = 0
    path: str = ""

    def time(self, sample):
        return self.start_s + np.asarray(sample, float) / self.sr


@dataclass
class Observation:
    i: str
    j: str
    event: int
    t_i: float
    t_j: float
    lag: float
    psr: float
    weight: float
    residual_s: float = 0.0
    inlier: bool = True


@dataclass
class ClapResult:
    clocks: dict[str, ClockModel]
    reference: str
    events_t: np.ndarray                      # (K,) reference camera's time of each event
    anchors: dict[str, dict[int, int]]        # camera -> event -> onset sample
    observations: list[Observation]
    loop_closure_ms: np.ndarray               # (L,) one per event and camera triple
    camera_diagnostics: dict[str, dict]
    diagnostics: dict
    curves: dict[tuple[str, str, int], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    onsets: dict[str, Onsets] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------
def match_onsets(t_ref: np.ndarray, t_cam: np.ndarray, tol: float, max_offset: float | None = None
                 ) -> tuple[float, float, np.ndarray]:
    """Match onset times of a camera to the reference camera's.

    Returns (offset, rate, pairs (M, 2) of indices into t_ref, t_cam) with
    t_ref ~ (1 + rate) t_cam + offset. Coarse offset by voting over all differences, then
    a line fit and a tight re-match (drift of hundreds of ppm over long takes is allowed).
    """
    if len(t_ref) == 0 or len(t_cam) == 0:
        return 0.0, 0.0, np.zeros((0, 2), int)
    d = (t_ref[:, None] - t_cam[None, :]).ravel()
    if max_offset is not None:
        d = d[np.abs(d) <= max_offset]
        if d.size == 0:
            return 0.0, 0.0, np.zeros((0, 2), int)
    ds = np.sort(d)
    lo = np.searchsorted(ds, ds - tol)
    hi = np.searchsorted(ds, ds + tol, side="right")
    votes = hi - lo
    best = np.flatnonzero(votes == votes.max())
    # among ties prefer the tightest cluster
    spread = [np.std(ds[lo[b]:hi[b]]) for b in best]
    b = best[int(np.argmin(spread))]
    offset = float(np.median(ds[lo[b]:hi[b]]))
    rate = 0.0
    pairs = np.zeros((0, 2), int)
    for tol_i in (tol, tol / 4, 0.01, 0.005):
        pred = (1 + rate) * t_cam + offset
        j = np.searchsorted(t_ref, pred)
        jl = np.clip(j - 1, 0, len(t_ref) - 1)
        jr = np.clip(j, 0, len(t_ref) - 1)
        nearest = np.where(np.abs(t_ref[jl] - pred) <= np.abs(t_ref[jr] - pred), jl, jr)
        ok = np.abs(t_ref[nearest] - pred) <= tol_i
        if ok.sum() == 0:
            break
        pairs = np.stack([nearest[ok], np.flatnonzero(ok)], 1)
        # one camera onset per reference onset
        _, first = np.unique(pairs[:, 0], return_index=True)
        pairs = pairs[np.sort(first)]
        if len(pairs) >= 2 and np.ptp(t_cam[pairs[:, 1]]) > 1.0:
            lf = robust_line(t_cam[pairs[:, 1]], t_ref[pairs[:, 0]], scale_floor=1e-4)
            rate, offset = lf.slope - 1.0, lf.intercept
            if abs(rate) > 2e-3:  # not a clock: fall back to a pure offset
                rate, offset = 0.0, float(np.median(t_ref[pairs[:, 0]] - t_cam[pairs[:, 1]]))
        else:
            offset = float(np.median(t_ref[pairs[:, 0]] - t_cam[pairs[:, 1]]))
    return offset, rate, pairs


def _window(tr: Track, center: int, pre: int, post: int) -> np.ndarray | None:
    a, b = center - pre, center + post
    if a < 0 or b > len(tr.x):
        return None
    w = tr.x[a:b].copy()
    w *= signal.windows.tukey(len(w), 0.2)
    return w


def clap_sync(tracks: Mapping[str, Track], reference: str, settings: ClapSettings | None = None,
              clap_positions: np.ndarray | None = None, mic_positions: Mapping[str, np.ndarray] | None = None,
              keep_curves: int = 6) -> ClapResult:
    """Solve every camera's clock relative to ``reference`` from claps (see module docstring)."""
    st = settings or ClapSettings()
    names = list(tracks)
    sr = tracks[reference].sr
    if any(t.sr != sr for t in tracks.values()):
        raise ValueError("clap_sync needs all tracks at one sample rate (resample first)")
    # 1. onsets
    onsets: dict[str, Onsets] = {}
    hp: dict[str, np.ndarray] = {}
    for n in names:
        tr = tracks[n]
        hp[n] = highpass(tr.x, sr)
        onsets[n] = detect_onsets(tr.x, sr, st.threshold_db, st.min_separation_s, x_hp=hp[n])
    for n in names:
        if len(onsets[n].sample_n) == 0:
            tr = tracks[n]
            raise UserError(
                f"no clap found in {tr.path or n}: looked for sharp onsets {st.threshold_db:g} dB above the "
                f"background in {tr.start_s:.2f}-{tr.start_s + len(tr.x) / sr:.2f} s (camera time) of audio "
                f"channel {tr.channel}",
                "clap sharply once or more where every camera hears it, or lower clap.threshold_db in the preset, "
                "or sync by --method ltc/tmcd")
    # 2. matching against the reference camera
    t_on = {n: tracks[n].time(onsets[n].sample_n) for n in names}
    approx: dict[str, tuple[float, float]] = {reference: (0.0, 0.0)}
    anchors: dict[str, dict[int, int]] = {n: {} for n in names}
    for k, s in enumerate(onsets[reference].sample_n):
        anchors[reference][k] = int(s)
    for n in names:
        if n == reference:
            continue
        off, rate, pairs = match_onsets(t_on[reference], t_on[n], st.match_tolerance_s, st.max_offset_s)
        if len(pairs) == 0:
            raise UserError(
                f"no clap in {tracks[n].path or n} matches one in {tracks[reference].path or reference}: "
                f"{len(t_on[n])} and {len(t_on[reference])} onsets, none line up",
                "make sure both cameras recorded the same claps (check the takes overlap), or choose another "
                "--reference")
        approx[n] = (off, rate)
        for kr, kc in pairs:
            anchors[n][int(kr)] = int(onsets[n].sample_n[kc])
    events = sorted(k for k in anchors[reference] if sum(k in anchors[n] for n in names) >= 2)
    if not events:
        raise UserError("no clap was heard by two cameras", "clap where every camera hears it")
    # sound travel
    dist = _distances(names, events, clap_positions, mic_positions, st.speed_of_sound)
    # 3. GCC-PHAT per event and pair
    pre = int(round(st.window_pre_ms * 1e-3 * sr))
    post = int(round(st.window_post_ms * 1e-3 * sr))
    max_lag = st.max_lag_ms * 1e-3 * sr
    obs: list[Observation] = []
    curves: dict = {}
    for k in events:
        have = [n for n in names if k in anchors[n]]
        for i, j in combinations(have, 2):
            wi = _window(tracks[i], anchors[i][k], pre, post)
            wj = _window(tracks[j], anchors[j][k], pre, post)
            if wi is None or wj is None:
                continue
            g = gcc_phat(wi, wj, sr, max_lag, st.beta, st.band_hz)
            if g.psr < st.min_psr or abs(g.lag) >= max_lag - 1:
                continue
            t_i = tracks[i].time(anchors[i][k])
            t_j = tracks[j].time(anchors[j][k] + g.lag)
            obs.append(Observation(i, j, k, float(t_i), float(t_j), g.lag, g.psr, float(min(g.psr, 50.0))))
            if reference in (i, j) and len([c for c in curves if c[:2] == (i, j)]) < keep_curves:
                curves[(i, j, k)] = (g.lags_m / sr * 1e3, g.curve_m)
    for n in names:
        if n != reference and not any(n in (o.i, o.j) for o in obs):
            raise UserError(f"the claps in {tracks[n].path or n} give no clear correlation peak with the other cameras",
                            "clap closer to the cameras and away from walls, or sync by --method ltc/tmcd")
    # 4. joint solve
    clocks, cov, drift = _solve(names, reference, obs, dist, events, tracks)
    est_positions = None
    if dist is None and mic_positions is not None and st.estimate_positions and \
            all(n in mic_positions for n in names):
        # sound travel from clap positions estimated with the clocks (a weak prior keeps
        # them near the rig's centre where the time differences leave them free)
        est_positions, dist = _estimate_positions(names, reference, obs, events, mic_positions, clocks, drift,
                                                  st.speed_of_sound, st.position_prior_m)
        clocks, cov, drift = _solve(names, reference, obs, dist, events, tracks)
    # 5. loop consistency
    lag_of = {(o.i, o.j, o.event): o.lag for o in obs}
    closure = []
    for k in events:
        have = [n for n in names if k in anchors[n]]
        for i, j, l in combinations(have, 3):
            if (i, j, k) in lag_of and (j, l, k) in lag_of and (i, l, k) in lag_of:
                closure.append((lag_of[(i, j, k)] + lag_of[(j, l, k)] - lag_of[(i, l, k)]) / sr * 1e3)
    closure = np.asarray(closure, float)
    # diagnostics
    cam_diag: dict[str, dict] = {}
    for n in names:
        mine = [o for o in obs if n in (o.i, o.j)]
        res = np.array([o.residual_s for o in mine if o.inlier]) * 1e3
        psr = np.array([o.psr for o in mine])
        d = {
            "events": len({o.event for o in mine}),
            "median_psr": float(np.median(psr)) if psr.size else 0.0,
            "residual_rms_ms": float(np.sqrt(np.mean(res ** 2))) if res.size else 0.0,
            "outliers": int(sum(not o.inlier for o in mine)),
            "channel": tracks[n].channel,
            "drift_measured": bool(drift),
        }
        if n != reference:
            d["offset_sd_ms"] = float(np.sqrt(cov[n][0]) * 1e3)
            d["rate_sd_ppm"] = float(np.sqrt(cov[n][1]) * 1e6) if drift else None
            conf = _confidence(d["median_psr"], d["residual_rms_ms"], d["events"], drift)
            clocks[n].confidence = conf
        else:
            clocks[n].confidence = 1.0
        cam_diag[n] = d
    t_ev = tracks[reference].time([anchors[reference][k] for k in events])
    diag = {
        "events": len(events), "event_times_s": [round(float(t), 6) for t in t_ev],
        "observations": len(obs), "loop_closure_max_ms": float(np.abs(closure).max()) if closure.size else 0.0,
        "loop_closure_rms_ms": float(np.sqrt(np.mean(closure ** 2))) if closure.size else 0.0,
        "sound_travel_corrected": dist is not None,
        "clap_positions": "known" if clap_positions is not None and mic_positions is not None else
        ("estimated" if est_positions is not None else "unknown"),
        "drift_measured": bool(drift),
    }
    if closure.size and diag["loop_closure_max_ms"] > st.loop_tolerance_ms:
        raise UserError(
            f"clap delays are inconsistent around camera loops (up to {diag['loop_closure_max_ms']:.2f} ms, "
            f"tolerance {st.loop_tolerance_ms:g} ms): echoes or other sharp sounds were taken for the clap",
            "clap in the open, away from walls, or raise clap.loop_tolerance_ms in the preset")
    if est_positions is not None:
        diag["estimated_clap_positions_m"] = [[round(float(v), 3) for v in p] for p in est_positions]
    return ClapResult(clocks, reference, np.asarray(t_ev), anchors, obs, closure, cam_diag, diag, curves, onsets)


def _distances(names, events, clap_positions, mic_positions, speed: float) -> dict | None:
    """Sound travel time (s) from each clap to each camera, when both positions are known."""
    if clap_positions is None or mic_positions is None:
        return None
    P = np.asarray(clap_positions, float).reshape(-1, 3)
    if len(P) == 1:
        P = np.repeat(P, len(events), 0)
    if len(P) != len(events):
        raise UserError(f"{len(P)} clap positions given but {len(events)} claps were found",
                        "list one position per clap in time order, or a single position for all")
    missing = [n for n in names if n not in mic_positions]
    if missing:
        raise UserError(f"no position for camera(s) {', '.join(missing)} in the calibration",
                        "calibrate every camera, or drop clap_positions")
    return {(n, k): float(np.linalg.norm(P[e] - np.asarray(mic_positions[n], float))) / speed
            for n in names for e, k in enumerate(events)}


def _estimate_positions(names, reference, obs, events, mic_positions, clocks, drift, speed, prior_m):
    """Clap positions (K, 3) and travel times, jointly with the clocks, by robust nonlinear least
    squares on all pair observations plus a Gaussian prior around the microphones' centroid."""
    from scipy.optimize import least_squares

    others = [n for n in names if n != reference]
    M = {n: np.asarray(mic_positions[n], float) for n in names}
    p0 = np.mean([M[n] for n in names], axis=0)
    ev_idx = {k: e for e, k in enumerate(events)}
    npar = 2 if drift else 1
    th0 = np.concatenate([[clocks[n].offset] + ([clocks[n].rate] if drift else []) for n in others])
    x0 = np.concatenate([th0, np.tile(p0, len(events))])
    I = np.array([names.index(o.i) for o in obs])
    J = np.array([names.index(o.j) for o in obs])
    E = np.array([ev_idx[o.event] for o in obs])
    ti = np.array([o.t_i for o in obs])
    tj = np.array([o.t_j for o in obs])
    w = np.sqrt(np.array([o.weight for o in obs]) / max(np.mean([o.weight for o in obs]), 1e-9))
    mics = np.stack([M[n] for n in names])
    sigma = 2e-5  # 0.02 ms: typical GCC precision

    def unpack(x):
        off = np.zeros(len(names))
        rate = np.zeros(len(names))
        for c, n in enumerate(others):
            off[names.index(n)] = x[npar * c]
            if drift:
                rate[names.index(n)] = x[npar * c + 1]
        return off, rate, x[npar * len(others):].reshape(-1, 3)

    def resid(x):
        off, rate, P = unpack(x)
        d_i = np.linalg.norm(P[E] - mics[I], axis=1) / speed
        d_j = np.linalg.norm(P[E] - mics[J], axis=1) / speed
        r = ((1 + rate[J]) * tj + off[J] - d_j) - ((1 + rate[I]) * ti + off[I] - d_i)
        return np.r_[w * r / sigma, (P - p0).ravel() / prior_m]

    sol = least_squares(resid, x0, loss="soft_l1", f_scale=3.0, x_scale="jac")
    _, _, P = unpack(sol.x)
    dist = {(n, k): float(np.linalg.norm(P[e] - M[n])) / speed for n in names for e, k in enumerate(events)}
    return P, dist


def _solve(names, reference, obs: list[Observation], dist, events, tracks):
    """Robust weighted least squares for (offset, rate) of every camera but the reference."""
    others = [n for n in names if n != reference]
    col = {n: i for i, n in enumerate(others)}
    t_obs = np.array([[o.t_i, o.t_j] for o in obs])
    span = {n: np.ptp(np.r_[t_obs[[o.i == n for o in obs], 0], t_obs[[o.j == n for o in obs], 1]])
            for n in others}
    drift = len({o.event for o in obs}) >= 2 and all(s > 1.0 for s in span.values())
    npar = 2 if drift else 1
    m = len(obs)
    A = np.zeros((m, npar * len(others)))
    y = np.zeros(m)
    w0 = np.array([o.weight for o in obs])
    for r, o in enumerate(obs):
        tc = 0.0
        if dist is not None:
            tc = dist[(o.j, o.event)] - dist[(o.i, o.event)]
        y[r] = o.t_i - o.t_j + tc
        if o.j != reference:
            A[r, npar * col[o.j]] = 1.0
            if drift:
                A[r, npar * col[o.j] + 1] = o.t_j
        if o.i != reference:
            A[r, npar * col[o.i]] -= 1.0
            if drift:
                A[r, npar * col[o.i] + 1] -= o.t_i
    inl = np.ones(m, bool)
    w = w0.copy()
    theta = np.zeros(A.shape[1])
    for _ in range(8):
        sw = np.sqrt(w * inl)
        theta, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
        r = y - A @ theta
        s = max(1.4826 * float(np.median(np.abs(r[inl]))), 2e-6)
        inl = np.abs(r) <= 6 * s
        w = w0 * np.minimum(1.0, 1.5 * s / np.maximum(np.abs(r), 1e-30))
    r = y - A @ theta
    sw = np.sqrt(w * inl)
    dof = max(int(inl.sum()) - A.shape[1], 1)
    sigma2 = max(float(np.sum((r * sw) ** 2) / max(np.sum(w * inl), 1e-30) * inl.sum() / dof), 1e-14)
    N = (A * (w * inl)[:, None]).T @ A
    try:
        C = np.linalg.inv(N) * sigma2 * np.sum(w * inl) / max(inl.sum(), 1)
    except np.linalg.LinAlgError:
        C = np.full((A.shape[1], A.shape[1]), np.inf)
    for o, ri, ok in zip(obs, r, inl):
        o.residual_s, o.inlier = float(ri), bool(ok)
    clocks = {reference: ClockModel(0.0, 0.0, "clap", 1.0)}
    cov = {}
    for n in others:
        c = npar * col[n]
        clocks[n] = ClockModel(float(theta[c]), float(theta[c + 1]) if drift else 0.0, "clap", 0.0)
        cov[n] = (float(C[c, c]), float(C[c + 1, c + 1]) if drift else 0.0)
    return {n: clocks[n] for n in names}, cov, drift


def _confidence(median_psr: float, rms_ms: float, n_events: int, drift: bool) -> float:
    """In [0, 1]: strong correlation peaks, consistent events and a measured drift -> near 1."""
    peak = float(np.clip((median_psr - 3.0) / 7.0, 0.0, 1.0))
    consistency = float(np.exp(-(rms_ms / 0.5) ** 2))
    events = 1.0 if drift else 0.7
    return round(peak * consistency * events, 4)
