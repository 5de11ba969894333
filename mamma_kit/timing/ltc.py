"""LTC (SMPTE 12M linear timecode) decoder, every frame tied to its audio sample.

Steps (all vectorised over the take):
1. Transitions, from either form a channel may carry:
   - square (a line input): a hysteresis comparator (thresholds at +-30 % of the signal's
     level) finds each level change; its time is the zero crossing just before, interpolated
     linearly between samples (sub-sample).
   - differentiated (an AC-coupled or high-passed input): each transition arrives as a short
     spike, often clipped, decaying back to the mid level; biphase mark flips the level at
     every transition, so the spikes alternate in sign and the same comparator (on the spike
     peaks) finds them. Each spike is read through a first-order high-pass model: the pole
     (decay per sample) is measured on the spikes' unclipped tails, clipped samples are
     restored from the tail that follows them, and the filter is inverted over the spike
     (d[n] = y[n] - a y[n-1], the steps of the square that went in); the transition time is
     the centroid of those steps, as the square form's zero crossing is of its ramp.
   Which form: a square holds its level until the next transition, a spike has decayed by
   then (``_level_kept``); the other form is tried too when the judged one decodes fewer
   than 90 % of the frames its transitions span, and the one with more frames kept.
   (A square is centred on the midpoint of its two levels, a high-passed signal on its mean.)
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
    form: str = "square"       # "square" or "differentiated" (high-passed input: spikes)

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


# square form: comparator thresholds as a fraction of the level (90th percentile of |x|):
# well above noise, well below the level a square holds between transitions
SQUARE_HYST = 0.3
# differentiated form: comparator thresholds as a fraction of each sign's extreme (99.9th
# percentile): a spike whose step falls across two samples still peaks above 0.55 of the
# highest (first-order high-pass, time constant down to a few tenths of a sample)
SPIKE_HYST = 0.35
# clipped samples (their true value unknown): those near the top cluster's level c (median of
# the samples above 90 % of the extreme), within 4 robust sigmas of that cluster (a clipped
# plateau's spread is the noise), at least 1 % and at most 10 % of c. An unclipped peak
# flagged by mistake is restored from its tail, which the model gets right too.
CLIP_TOP = 0.9
CLIP_SIGMAS = 4.0
CLIP_MARGIN = (0.01, 0.1)
# tail samples used to measure the pole: above the noise, below the clip level
TAIL_RANGE = (0.15, 0.9)
# tail samples fitted (least squares along the decay) to restore a clipped run: averages
# the noise the restoration multiplies by a^-k
TAIL_FIT = 4
# a step part of at least 10 % of the clip level in the sample before a clipped run means
# the transition began there (so the run's first sample completes it): such spikes give the
# step height
PARTIAL_MIN = 0.1
# the square form holds its level until the next transition (ratio of the level just before
# it to the level just after the last one, near 1); a high-passed spike has decayed by then
LEVEL_KEPT_MIN = 0.7
# the judged form is kept if it decodes 90 % of the frames its transitions span; else the
# other form is tried too and the one with more frames kept
FORM_KEEP = 0.9


def _state_changes(x: np.ndarray, hi: float, lo: float) -> tuple[np.ndarray, np.ndarray]:
    """Hysteresis comparator on ``x`` (N,): the (K,) indices where the state flips (the first
    sample above ``hi`` after being below ``lo``, or the reverse) and the (K,) new states +-1."""
    s = np.where(x > hi, 1, np.where(x < lo, -1, 0)).astype(np.int8)
    idx = np.where(s != 0, np.arange(len(s)), 0)
    np.maximum.accumulate(idx, out=idx)
    state = s[idx]
    ch = np.flatnonzero((state[1:] != state[:-1]) & (state[:-1] != 0)) + 1
    return ch, state[ch]


def _transitions(x: np.ndarray, hyst: float) -> np.ndarray:
    """Sub-sample times (in samples) of the level changes of a two-level signal."""
    ch, _ = _state_changes(x, hyst, -hyst)
    pos = x >= 0
    zc = np.flatnonzero(pos[1:] != pos[:-1])
    k = np.searchsorted(zc, ch) - 1
    ok = k >= 0
    z = zc[k[ok]]
    x0, x1 = x[z], x[z + 1]
    return z + x0 / (x0 - x1)


def _extremes(x: np.ndarray) -> tuple[float, float]:
    """The positive and negative extremes of ``x`` (both >= 0): robust to a few outliers."""
    return float(np.percentile(x, 99.9)), float(-np.percentile(x, 0.1))


def _level_kept(x: np.ndarray) -> float:
    """How well ``x`` (N,) holds its level between the comparator's transitions: median over
    transitions of (level 2 samples before the next transition) / (level 2 samples after this
    one), in the transition's sign. About 1 for a square, well below 1 for high-passed spikes
    that decay back to the mean; 0 when there are too few transitions to say."""
    top, bot = _extremes(x)
    if min(top, bot) < 1e-4:
        return 0.0
    ch, st = _state_changes(x, SPIKE_HYST * top, -SPIKE_HYST * bot)
    if len(ch) < 20:
        return 0.0
    after = np.minimum(ch[:-1] + 2, len(x) - 1)
    before = np.maximum(ch[1:] - 2, after)
    ok = (ch[1:] - ch[:-1]) >= 6  # room for both samples away from the two transitions
    if ok.sum() < 10:
        return 0.0
    num = st[:-1][ok] * x[before[ok]]
    den = st[:-1][ok] * x[after[ok]]
    return float(np.median(num / np.maximum(den, 1e-12)))


def _spike_transitions(x: np.ndarray) -> np.ndarray:
    """Sub-sample transition times (in samples) of LTC that went through a first-order
    high-pass (an AC-coupled input): ``x`` (N,) holds alternating-sign spikes, maybe clipped.

    Model: y[n] = a (y[n-1] + u[n] - u[n-1]) for the square u; so d[n] = y[n] - a y[n-1] is
    the square's step, spread over the two samples the transition falls across (in
    proportion to where it falls), and after a spike y decays by a per sample. With the pole
    a from the unclipped tails, a clipped run is restored from the tail after it
    (y = y_tail a^-k); if the run's first sample is where the step began, its share of the
    step follows from the step height S (the same for every transition: the square has two
    levels). The transition time is the centroid of d over the spike's three samples, minus
    half a sample (d[n] sits between samples n-1 and n) -- exact under the model, like the
    square form's zero crossing of a sampled ramp."""
    n = len(x)
    top, bot = _extremes(x)
    if min(top, bot) < 1e-4 or n < 16:
        return np.zeros(0)
    ch, sg = _state_changes(x, SPIKE_HYST * top, -SPIKE_HYST * bot)
    keep = (ch >= 3) & (ch < n - 4)
    ch, sg = ch[keep], sg[keep].astype(np.float64)
    if len(ch) < 20:
        return np.zeros(0)
    ext = np.where(x >= 0, top, bot)  # (N,) each sample's extreme, by its sign
    clip_lv = []
    for side, e in ((x, top), (-x, bot)):
        hi = side[side >= CLIP_TOP * e]
        c = float(np.median(hi)) if len(hi) else e
        sig = 1.4826 * float(np.median(np.abs(hi - c))) if len(hi) else 0.0
        clip_lv.append(c - float(np.clip(CLIP_SIGMAS * sig, CLIP_MARGIN[0] * c, CLIP_MARGIN[1] * c)))
    clipped = np.where(x >= 0, x >= clip_lv[0], -x >= clip_lv[1])
    # a decaying spike cannot dip below the clip and come back: a one-sample hole in a
    # clipped run is noise on the plateau
    clipped[1:-1] |= clipped[:-2] & clipped[2:] & (np.sign(x[:-2]) == np.sign(x[2:]))
    # the pole: ratio of successive tail samples (same sign, decaying, neither clipped)
    v0, v1 = np.abs(x[:-1]), x[1:] * np.sign(x[:-1])
    e0 = ext[:-1]
    tail = ((v0 > TAIL_RANGE[0] * e0) & (v0 < TAIL_RANGE[1] * e0) & (v1 > 0.2 * TAIL_RANGE[0] * e0)
            & (v1 < v0) & ~clipped[:-1] & ~clipped[1:])
    a = float(np.clip(np.median(v1[tail] / v0[tail]), 0.0, 0.99)) if tail.sum() >= 20 else 0.0
    # next unclipped sample at or after each index (a run's end)
    nxt = np.where(~clipped, np.arange(n), n - 1)
    nxt = np.minimum.accumulate(nxt[::-1])[::-1]
    # each spike's three samples b, b+1, b+2: b+1 is the first clipped sample if the
    # comparator's sample or the one after is clipped, else the comparator's sample
    c0, c1 = clipped[ch], clipped[np.minimum(ch + 1, n - 1)]
    is_clip = c0 | c1
    m0 = np.where(c0, ch, np.where(c1, ch + 1, ch))
    b = m0 - 1
    v = sg[:, None] * x[b[:, None] + np.arange(-1, 3)[None, :]]  # (K, 4): samples b-1 .. b+2
    # the previous spike still clipped at b-1 (a short interval): its true value there is
    # beyond the clip level, and at least what its decay into b implies (b its pure tail, no
    # step in b); a b short of that holds the start of this step
    prev_clip = clipped[b - 1]
    if a > 0:
        v[prev_clip, 0] = np.minimum(v[prev_clip, 0], v[prev_clip, 1] / a)
    d = v[:, 1:] - a * v[:, :-1]                               # (K, 3): steps at b, b+1, b+2
    # a clipped run's true values: back along the decay from the tail after it (its first
    # unclipped sample m and up to TAIL_FIT - 1 more before the next spike, least squares)
    m = nxt[np.minimum(m0 + 1, n - 1)]
    j = np.arange(TAIL_FIT)
    idx = np.minimum(m[:, None] + j[None, :], n - 1)
    use = (idx < np.r_[ch[1:], n][:, None] - 1) & ~clipped[idx]
    use[:, 0] = True
    aj = a ** j.astype(float)
    vm = (use * sg[:, None] * x[idx]) @ aj / (use @ (aj * aj))  # fitted tail value at m
    y_m0 = vm * a ** (m0 - m).astype(float) if a > 0 else vm
    y_m1 = np.where(m > m0 + 1, vm * a ** (m0 + 1 - m).astype(float) if a > 0 else vm, v[:, 3])
    # the step height, from unclipped spikes and from clipped ones whose step began at b
    began = is_clip & (d[:, 0] > PARTIAL_MIN * ext[m0])
    s_unclip = d.sum(1)
    s_began = d[:, 0] + y_m0 - a * v[:, 1]
    cand = np.r_[s_unclip[~is_clip], s_began[began]]
    if len(cand) >= 10:
        S = float(np.median(cand))
    elif is_clip.any():  # every step began inside a clipped sample: a lower bound at best
        S = float(np.percentile(s_began[is_clip], 10))
    else:
        S = float(np.median(s_unclip))
    # clipped spikes: the share of the step at b+1 and b+2 from the restored sample b+2
    R = np.maximum(S - d[:, 0], 0.0)
    Q = y_m1 - a * a * v[:, 1]
    d1 = np.clip((R - Q) / (1.0 - a), 0.0, R)
    d_clip = np.stack([np.maximum(d[:, 0], 0.0), d1, R - d1], 1)
    w = np.where(is_clip[:, None], d_clip, np.maximum(d, 0.0))
    tot = w.sum(1)
    ok = tot > 0
    t = b[ok] + (w[ok] @ np.arange(3.0)) / tot[ok] - 0.5
    return t[np.r_[True, np.diff(t) > 0]] if len(t) else t


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


def _empty(sr: int, form: str = "square") -> LtcFrames:
    return LtcFrames(np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.uint32), np.zeros(0, bool),
                     np.zeros(0, bool), 0, 0.0, sr, 0, form=form)


def _centred(x: np.ndarray) -> np.ndarray:
    """``x`` minus the midpoint of its two levels (5th and 95th percentiles): a square's
    transitions cross it half-way whatever share of the take each level holds (the median of
    a two-level signal is one of the levels when they are not held equally long)."""
    lo, hi = np.percentile(x, [5, 95])
    return x - 0.5 * (lo + hi)


def ltc_form(x: np.ndarray) -> str:
    """Which form a centred channel ``x`` (N,) carries: "square" (holds its level between
    transitions) or "differentiated" (spikes that decay back to the mean)."""
    return "square" if _level_kept(x) >= LEVEL_KEPT_MIN else "differentiated"


def decode_ltc(x: np.ndarray, sr: int, fps_hint: float | None = None, form: str | None = None) -> LtcFrames:
    """Decode every LTC frame in a mono signal ``x`` (N,) (see the module docstring).

    form: "square", "differentiated" or None (judged from the signal; the other form is
    tried too when the judged one misses frames, see the module docstring)."""
    x = np.asarray(x, np.float64)
    if len(x) == 0:
        return _empty(sr)
    xs = _centred(x)
    if float(np.percentile(np.abs(xs), 99.9)) < 1e-4:
        return _empty(sr)
    forms = [form] if form else [ltc_form(xs)]
    if not form:
        forms.append("differentiated" if forms[0] == "square" else "square")
    best = _empty(sr, forms[0])
    for f in forms:
        if f == "square":
            amp = float(np.percentile(np.abs(xs), 90))
            tr = _transitions(xs, SQUARE_HYST * amp) if amp >= 1e-4 else np.zeros(0)
        else:  # a high-passed signal has no DC: its mid level is the mean (neither the median
            # nor the levels' midpoint are: the decaying tails need not be symmetric)
            tr = _spike_transitions(x - np.mean(x))
        fr = _decode_transitions(tr, sr, fps_hint, f)
        if fr.n > best.n:
            best = fr
        # the judged form is kept when it decodes nearly every frame its transitions span
        span_frames = (fr.span[1] - fr.span[0]) / (80 * fr.bit_period) if fr.n else 0.0
        if fr.n and fr.n >= FORM_KEEP * span_frames - 2:
            break
    return best


def _decode_transitions(tr: np.ndarray, sr: int, fps_hint: float | None, form: str) -> LtcFrames:
    """Steps 2-4 of the module docstring on the (M,) sub-sample transition times ``tr``."""
    empty = _empty(sr, form)
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
                     bit_period, sr, len(tr), (float(tr[0]), float(tr[-1])), form)


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
    """LTC in either form, unlike microphone sound: a two-level signal (most samples near
    +-amplitude), or high-passed LTC (alternating-sign spikes whose intervals are one bit or
    half a bit, ``_regular_spikes``)."""
    x = np.asarray(x, np.float64)
    if len(x) == 0:
        return False
    a = np.abs(_centred(x))
    p99 = float(np.percentile(a, 99))
    if p99 < 1e-4:
        return False
    return float(np.percentile(a, 30)) >= 0.3 * p99 or _regular_spikes(x - np.mean(x))


# high-passed LTC: at least this share of the comparator's intervals within +-20 % of the
# bit period or half of it (noise and speech spread their crossings over all intervals)
SPIKE_REGULAR_MIN = 0.9
SPIKE_REGULAR_TOL = 0.2
SPIKE_KIND_MIN = 0.05


def _regular_spikes(x: np.ndarray) -> bool:
    """Whether the alternating-sign spikes of ``x`` (N,) come at one bit period or half of it,
    as biphase mark's transitions do (scale-free: the period from the intervals themselves)."""
    top, bot = _extremes(x)
    if min(top, bot) < 1e-4:
        return False
    ch, _ = _state_changes(x, SPIKE_HYST * top, -SPIKE_HYST * bot)
    if len(ch) < 200:
        return False
    d = np.diff(ch).astype(np.float64)
    med = float(np.median(d))  # intervals are T/2 or T: the median lies between
    if med < 2:
        return False
    T = _bit_period(d[:: max(1, len(d) // 4000)], 0.95 * med, 2.1 * med)
    whole = np.abs(d / T - 1) <= SPIKE_REGULAR_TOL
    half = np.abs(2 * d / T - 1) <= SPIKE_REGULAR_TOL
    # both kinds present (every LTC word's sync word has 4 zeros and 12 ones): not a tone
    return (float((whole | half).mean()) >= SPIKE_REGULAR_MIN
            and min(float(whole.mean()), float(half.mean())) >= SPIKE_KIND_MIN)


def find_ltc_channel(samples_nc: np.ndarray, sr: int, fps_hint: float | None = None
                     ) -> tuple[int, LtcFrames] | None:
    """The channel of ``samples_nc`` (N, C) carrying LTC, square or high-passed (the one with
    most decoded frames), or None."""
    best = None
    for c in range(samples_nc.shape[1]):
        x = samples_nc[:, c]
        if not looks_like_ltc(x):
            continue
        fr = decode_ltc(x, sr, fps_hint)
        if fr.n and (best is None or fr.n > best[1].n):
            best = (c, fr)
    return best
