"""LTC (SMPTE 12M linear timecode) decoder, every frame tied to its audio sample.

Steps (all vectorised over the take):
1. Transitions: a hysteresis comparator (thresholds at +-30 % of the signal's level) finds
   each level change; its time is the zero crossing just before, interpolated linearly
   between samples (sub-sample).
2. Adaptive bit period: intervals between transitions are one bit (a 0) or half a bit (half
   of a 1). A first period comes from the interval distribution, then a running local
   period (moving average of the bit lengths the intervals imply) reclassifies them, so
   varispeed and drifting sample clocks are followed. Intervals that are neither (dropouts,
   noise) cut the stream into segments.
3. Biphase mark: within a segment transitions are numbered in half-bits; bit boundaries are
   the transitions at which whole-bit intervals start (their parity), a 1 is a boundary
   followed by a transition half a bit later.
4. Frames: the sync word 0011 1111 1111 1101 (bits 64-79) found forwards, or reversed
   (1011 1111 1111 1100) for backwards playback; the 80 bits give BCD time, the drop-frame
   and colour flags and 32 user bits. Each frame's start is the time of its bit-0 boundary.

``ltc_clock`` fits camera time -> timecode time over all frames (robust line: offset and
drift) and reports the fraction of the take's frames that decoded.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np
from scipy import ndimage

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.timecode import STANDARD_RATES, frames_to_seconds, frames_to_timecode, rate_fraction
from mamma_kit.timing.fit import LineFit, robust_line

SYNC = np.array([0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 1], np.uint8)
NOMINAL_RATES = np.array([24, 25, 30])


@dataclass
class LtcFrames:
    """Decoded LTC frames of one audio channel (F frames, in time order)."""
    start_f: np.ndarray        # (F,) float: sample position (sub-sample) of each frame's bit-0 boundary
    count_f: np.ndarray        # (F,) int: frames since 00:00:00:00 at the nominal rate
    user_bits_f: np.ndarray    # (F,) uint32
    drop_frame_f: np.ndarray   # (F,) bool
    reverse_f: np.ndarray      # (F,) bool: read backwards (reversed playback)
    nominal_fps: int
    bit_period: float          # median samples per bit
    sr: int
    n_transitions: int
    span: tuple[float, float] = (0.0, 0.0)  # samples of the first and last transition: where LTC is present

    @property
    def n(self) -> int:
        return len(self.start_f)

    def timecode(self, i: int, fps: float | None = None) -> str:
        return str(frames_to_timecode(int(self.count_f[i]), fps or self.nominal_fps, bool(self.drop_frame_f[i])))


def word_rate(fps: float) -> Fraction:
    """LTC words per second for a video rate: above 30 fps one word carries a frame pair
    (SMPTE 12-1 frame-pair convention), so 50/59.94/60 fps use 25/29.97/30 words per second."""
    r = rate_fraction(fps)
    return r / 2 if r > 31 else r


def _transitions(x: np.ndarray, hyst: float) -> np.ndarray:
    """Sub-sample times (in samples) of the level changes of a two-level signal."""
    s = np.where(x > hyst, 1, np.where(x < -hyst, -1, 0)).astype(np.int8)
    idx = np.where(s != 0, np.arange(len(s)), 0)
    np.maximum.accumulate(idx, out=idx)
    state = s[idx]
    ch = np.flatnonzero((state[1:] != state[:-1]) & (state[:-1] != 0)) + 1
    pos = x >= 0
    zc = np.flatnonzero(pos[1:] != pos[:-1])
    k = np.searchsorted(zc, ch) - 1
    ok = k >= 0
    z = zc[k[ok]]
    x0, x1 = x[z], x[z + 1]
    return z + x0 / (x0 - x1)


def _bit_period(d: np.ndarray, lo: float, hi: float) -> float:
    """The bit period T in [lo, hi] that puts the intervals d nearest to T or T/2.

    A grid search, then a finer one around the best: the median of d can fall between the
    two modes (about as many halves as wholes), so it is no estimate of either."""
    best = 0.5 * (lo + hi)
    for span, n in ((None, 200), (0.02, 41)):
        c = np.linspace(lo, hi, n) if span is None else best * np.linspace(1 - span, 1 + span, n)
        cost = np.minimum(np.abs(d[None] - c[:, None]), np.abs(d[None] - c[:, None] / 2)).sum(1) / c
        best = float(c[int(np.argmin(cost))])
    return best


def decode_ltc(x: np.ndarray, sr: int, fps_hint: float | None = None) -> LtcFrames:
    """Decode every LTC frame in a mono signal (see the module docstring)."""
    x = np.asarray(x, np.float64)
    x = x - np.median(x)
    amp = float(np.percentile(np.abs(x), 90)) if len(x) else 0.0
    empty = LtcFrames(np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.uint32), np.zeros(0, bool),
                      np.zeros(0, bool), 0, 0.0, sr, 0)
    if amp < 1e-4:
        return empty
    tr = _transitions(x, 0.3 * amp)
    if len(tr) < 200:
        return empty
    d = np.diff(tr)
    # 2. bit period: pick T so that intervals sit at T or T/2
    lo_T, hi_T = sr / (80 * 31.0), sr / (80 * 23.0)  # plausible bit periods, 23.976..30 words/s
    plaus = d[(d > 0.4 * lo_T) & (d < 1.3 * hi_T)]
    if len(plaus) < 100:
        return empty
    T = _bit_period(plaus[:: max(1, len(plaus) // 4000)], 0.8 * lo_T, 1.2 * hi_T)
    Tloc = np.full(len(d), T)
    for _ in range(3):
        u = d / Tloc
        long_ = (u > 0.75) & (u < 1.4)
        short = (u > 0.3) & (u <= 0.75)
        est = np.where(long_, d, np.where(short, 2 * d, 0.0))
        wgt = (long_ | short).astype(float)
        num = ndimage.uniform_filter1d(est, 65, mode="nearest")
        den = ndimage.uniform_filter1d(wgt, 65, mode="nearest")
        Tloc = np.where(den > 0.2, num / np.maximum(den, 1e-9), T)
    u = d / Tloc
    long_ = (u > 0.75) & (u < 1.4)
    short = (u > 0.3) & (u <= 0.75)
    valid = long_ | short
    half = np.where(long_, 2, 1)
    # 3. segments: cut at invalid intervals and where the boundary parity flips
    seg_break = ~valid
    P = np.zeros(len(tr), np.int64)  # half-bit position of each transition within its segment
    P[1:] = np.cumsum(np.where(valid, half, 0))
    seg_start = np.r_[0, np.flatnonzero(seg_break) + 1]
    seg_id = np.cumsum(np.r_[0, seg_break.astype(int)])  # per transition
    P = P - P[seg_start][seg_id]
    # parity of each long interval's start; a change within a segment is a glitch -> new segment
    li = np.flatnonzero(long_)
    par = P[li] % 2
    flip = np.zeros(len(tr), bool)
    same_seg = seg_id[li[1:]] == seg_id[li[:-1]]
    fl = li[1:][same_seg & (par[1:] != par[:-1])]
    flip[fl] = True
    seg2 = np.cumsum(np.r_[0, (seg_break | flip[1:]).astype(int)])  # new segment at flip transition
    first = np.r_[0, np.flatnonzero(np.diff(seg2)) + 1]
    P2 = P - P[first][np.searchsorted(first, np.arange(len(tr)), side="right") - 1]
    # phase per segment from its long intervals
    phase = np.full(seg2.max() + 1, -1)
    phase[seg2[li]] = P2[li] % 2
    ph = phase[seg2]
    boundary = (ph >= 0) & ((P2 - ph) % 2 == 0)
    bidx = np.flatnonzero(boundary)
    # a bit spans two consecutive boundaries in the same segment two half-bits apart
    nxt = bidx[1:]
    cur = bidx[:-1]
    okb = (seg2[nxt] == seg2[cur]) & (P2[nxt] - P2[cur] == 2)
    bit_val = ((P2[np.minimum(cur + 1, len(P2) - 1)] - P2[cur]) == 1).astype(np.uint8)
    # keep runs of contiguous bits; a gap starts a new run
    bits = bit_val[okb]
    b_start = tr[cur[okb]]
    b_end = tr[nxt[okb]]
    run = np.cumsum(np.r_[0, (cur[okb][1:] != nxt[okb][:-1]).astype(int)])
    n_bits = len(bits)
    if n_bits < 80:
        return empty
    # 4. sync words
    from numpy.lib.stride_tricks import sliding_window_view
    win = sliding_window_view(bits, 16)
    fwd = np.flatnonzero(np.all(win == SYNC, axis=1))
    rev = np.flatnonzero(np.all(win == SYNC[::-1], axis=1))
    fwd = fwd[(fwd >= 64)]
    fwd = fwd[run[fwd - 64] == run[fwd + 15]]
    rev = rev[rev + 80 <= n_bits]
    rev = rev[run[rev] == run[rev + 79]]
    frames_f = [bits[i - 64:i + 16] for i in fwd] + [bits[i:i + 80][::-1] for i in rev]
    if not frames_f:
        return empty
    F = np.stack(frames_f).astype(np.int64)
    start = np.r_[b_start[fwd - 64], b_end[rev + 79]]
    reverse = np.r_[np.zeros(len(fwd), bool), np.ones(len(rev), bool)]

    def field(a, n):
        return F[:, a:a + n] @ (1 << np.arange(n))

    fu, ft, su, st_, mu, mt, hu, ht = (field(0, 4), field(8, 2), field(16, 4), field(24, 3), field(32, 4),
                                       field(40, 3), field(48, 4), field(56, 2))
    ub = sum(field(4 + 8 * g, 4) << (4 * g) for g in range(8))  # user-bit groups 1..8
    drop = F[:, 10].astype(bool)
    frames = ft * 10 + fu
    secs, mins, hours = st_ * 10 + su, mt * 10 + mu, ht * 10 + hu
    # nominal rate: hint, else from the bit period
    bit_period = float(np.median(Tloc[valid])) if valid.any() else T
    if fps_hint:
        nominal = int(round(float(word_rate(fps_hint))))
    else:
        nominal = int(NOMINAL_RATES[np.argmin(np.abs(NOMINAL_RATES - sr / (80 * bit_period)))])
    good = ((fu <= 9) & (su <= 9) & (mu <= 9) & (hu <= 9) & (frames < nominal) & (secs < 60) & (mins < 60)
            & (hours < 24))
    total_min = hours * 60 + mins
    count = (total_min * 60 + secs) * nominal + frames
    dpm = 2 * nominal // 30
    count = np.where(drop, count - dpm * (total_min - total_min // 10), count)
    order = np.argsort(start[good], kind="stable")
    return LtcFrames(start[good][order], count[good][order].astype(np.int64),
                     ub[good][order].astype(np.uint32), drop[good][order], reverse[good][order], nominal,
                     bit_period, sr, len(tr), (float(tr[0]), float(tr[-1])))


@dataclass
class LtcClock:
    """Camera time -> timecode time for one camera, from its decoded frames."""
    clock: ClockModel          # t_tc = (1 + rate) t_cam + offset
    fps: float                 # true frame rate (e.g. 29.97002997)
    fps_name: str
    fit: LineFit
    t_cam_f: np.ndarray        # (F,) camera time of each decoded frame's start
    t_tc_f: np.ndarray         # (F,) its timecode time
    decoded: int
    expected: int
    first_tc: str
    last_tc: str
    user_bits: int
    drop_frame: bool
    reversed_frames: int

    @property
    def fraction(self) -> float:
        return self.decoded / self.expected if self.expected else 0.0


def ltc_clock(frames: LtcFrames, start_s: float, duration_s: float, fps: float | None = None) -> LtcClock:
    """Fit the camera's clock to the timecode: t_tc = (1 + rate) t_cam + offset."""
    fw = ~frames.reverse_f
    t_cam = start_s + frames.start_f / frames.sr
    cnt = frames.count_f
    drop = bool(np.median(frames.drop_frame_f)) if frames.n else False
    # true rate: hint, else drop-frame -> 30000/1001 family, else the nearest standard rate to
    # the measured frames per camera second (camera drift is far below the 0.1 % that separates
    # 29.97 from 30)
    if fps:
        rate = word_rate(fps)
    else:
        sel = fw if fw.sum() >= 2 else np.ones(frames.n, bool)
        meas = float(frames.nominal_fps)
        if sel.sum() >= 2 and np.ptp(t_cam[sel]) > 0:
            meas = float(robust_line(t_cam[sel], cnt[sel].astype(float), scale_floor=0.05).slope)
        fam = [r for r in STANDARD_RATES.values() if round(float(r)) == frames.nominal_fps]
        if drop:
            fam = [r for r in fam if r.denominator == 1001] or fam
        rate = min(fam, key=lambda r: abs(float(r) - abs(meas))) if fam else rate_fraction(meas)
    name = next((k for k, v in STANDARD_RATES.items() if v == rate), f"{float(rate):.3f}")
    t_tc = np.asarray(frames_to_seconds(cnt.astype(np.float64), rate), float)
    use = fw if fw.sum() >= 2 else np.ones(frames.n, bool)
    fit = robust_line(t_cam[use], t_tc[use], scale_floor=2e-6)
    clock = ClockModel(offset=fit.intercept, rate=fit.slope - 1.0, source="ltc")
    # expected: the complete frames between the first and last transition of the signal (the
    # decoded audio may run on past the recording: AAC padding), dropouts inside count as missed
    frame_dur = 1.0 / float(rate)
    a = max(start_s, start_s + frames.span[0] / frames.sr - 1.0 / frames.sr)
    b = min(start_s + duration_s, start_s + frames.span[1] / frames.sr + 1.0 / frames.sr)
    tc0 = fit.slope * a + fit.intercept
    tc1 = fit.slope * b + fit.intercept
    n0 = int(np.ceil(tc0 / frame_dur - 1e-6))
    n1 = int(np.floor(tc1 / frame_dur + 1e-6)) - 1
    expected = max(n1 - n0 + 1, 0)
    got = np.unique(np.round(t_tc[use][fit.inlier_n] / frame_dur).astype(np.int64))
    decoded = int(np.sum((got >= n0) & (got <= n1)))
    ub = 0
    if frames.n:
        vals, counts = np.unique(frames.user_bits_f, return_counts=True)
        ub = int(vals[np.argmax(counts)])
    return LtcClock(clock, float(rate), name, fit, t_cam, t_tc, decoded, expected,
                    frames.timecode(0, rate) if frames.n else "", frames.timecode(frames.n - 1, rate) if frames.n else "",
                    ub, drop, int(frames.reverse_f.sum()))


def looks_like_ltc(x: np.ndarray) -> bool:
    """A two-level signal (most samples near +-amplitude), unlike microphone sound."""
    a = np.abs(x - np.median(x))
    p99 = float(np.percentile(a, 99))
    return p99 >= 1e-4 and float(np.percentile(a, 30)) >= 0.3 * p99


def find_ltc_channel(samples_nc: np.ndarray, sr: int, fps_hint: float | None = None
                     ) -> tuple[int, LtcFrames] | None:
    """The channel carrying LTC (the one with most decoded frames), or None."""
    best = None
    for c in range(samples_nc.shape[1]):
        x = samples_nc[:, c]
        if not looks_like_ltc(x):
            continue
        fr = decode_ltc(x, sr, fps_hint)
        if fr.n and (best is None or fr.n > best[1].n):
            best = (c, fr)
    return best
