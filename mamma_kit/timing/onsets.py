"""Clap candidates: sharp onsets in an audio track.

A clap is a broadband burst that rises by tens of dB within a millisecond. The detector
works on the log energy of the high-passed signal in 1 ms hops and marks hops whose level
jumps ``threshold_db`` above the level of the preceding 20-200 ms (a local, causal
background, so reverberation tails and slow sounds such as speech do not fire), keeping the
strongest onset within ``min_separation_s``. Each onset is then refined to the sample
where the envelope first leaves the background noise. Pure numpy/scipy: no numba warm-up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, signal


@dataclass
class Onsets:
    sample_n: np.ndarray      # (K,) int: refined onset samples
    strength_db_n: np.ndarray  # (K,) rise above the preceding background (dB)
    hop: int
    threshold_db: float


def highpass(x: np.ndarray, sr: int, band: tuple[float, float] = (500.0, 8000.0)) -> np.ndarray:
    """Zero-phase 4th-order Butterworth band-pass over a clap's main band (drops rumble,
    wind and hiss outside it)."""
    sos = signal.butter(4, [band[0], min(band[1], 0.45 * sr)], "bandpass", fs=sr, output="sos")
    return signal.sosfiltfilt(sos, np.asarray(x, np.float64))


def detect_onsets(x: np.ndarray, sr: int, threshold_db: float = 8.0, min_separation_s: float = 0.25,
                  max_onsets: int = 500, hop_s: float = 0.001, x_hp: np.ndarray | None = None) -> Onsets:
    """Sharp onsets in a mono signal; see the module docstring."""
    xh = highpass(x, sr) if x_hp is None else x_hp
    hop = max(1, int(round(hop_s * sr)))
    n = len(xh) // hop
    if n < 10:
        return Onsets(np.zeros(0, int), np.zeros(0), hop, threshold_db)
    e = np.mean(xh[:n * hop].reshape(n, hop) ** 2, axis=1)
    level = 10 * np.log10(e + 1e-20)
    # background: median of the hops 20..200 ms before each hop (causal, skips the attack)
    win = max(3, int(round(0.18 / hop_s)))
    gap = int(round(0.02 / hop_s))
    med = ndimage.median_filter(level, size=win, mode="nearest")
    bg = np.full(n, np.inf)
    shift = gap + win // 2
    bg[shift:] = med[:n - shift]
    rise = level - bg
    # a clap also stands out against the level 2-5 ms before (sharp attack)
    pre = np.full(n, np.inf)
    pre[5:] = np.maximum.reduce([level[0:n - 5], level[1:n - 4], level[2:n - 3]])
    sharp = level - pre
    cand = (rise >= threshold_db) & (sharp >= 0.5 * threshold_db)
    if not cand.any():
        return Onsets(np.zeros(0, int), np.zeros(0), hop, threshold_db)
    # first hop of each run above threshold; keep the strongest per separation window
    idx = np.flatnonzero(cand)
    starts = idx[np.r_[True, np.diff(idx) > 3]]
    strength = np.array([rise[s:s + 4][np.isfinite(rise[s:s + 4])].max() for s in starts])
    order = np.argsort(-strength)
    sep = int(round(min_separation_s / hop_s))
    keep: list[int] = []
    taken = np.zeros(0, int)
    for o in order:
        s = starts[o]
        if taken.size and np.min(np.abs(taken - s)) < sep:
            continue
        keep.append(o)
        taken = np.r_[taken, s]
        if len(keep) >= max_onsets:
            break
    keep = np.array(sorted(keep, key=lambda o: starts[o]), int)
    samples = np.array([refine_onset(xh, sr, int(starts[o]) * hop) for o in keep], int)
    return Onsets(samples, strength[keep], hop, threshold_db)


def refine_onset(xh: np.ndarray, sr: int, around: int, search_s: float = 0.004) -> int:
    """The first sample near ``around`` where the smoothed envelope leaves the noise floor."""
    a = max(0, around - int(search_s * sr))
    b = min(len(xh), around + int(search_s * sr))
    nb = int(0.02 * sr)
    noise = xh[max(0, a - nb):a]
    floor = float(np.sqrt(np.mean(noise ** 2))) if len(noise) > 8 else 0.0
    seg = np.abs(xh[a:b])
    if len(seg) == 0:
        return around
    k = max(1, int(0.0002 * sr))
    env = np.convolve(seg, np.ones(k) / k, mode="same")
    peak = float(env.max())
    thr = max(4.0 * floor, floor + 0.15 * (peak - floor))
    above = np.flatnonzero(env > thr)
    return a + int(above[0]) if len(above) else around
