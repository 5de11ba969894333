"""SMPTE timecode arithmetic (shared by the LTC encoder in synth, the LTC decoder and tmcd in timing).

A timecode 'HH:MM:SS:FF' (';' before FF marks drop-frame) counts frames at a *nominal*
integer rate (24, 25, 30, 48, 50, 60); the frames themselves run at the true rate, e.g.
30000/1001 for "29.97". Drop-frame (29.97/59.94 only) skips frame labels 0 and 1 (0-3 at
59.94) at the start of every minute except each tenth, so the label stays close to the
wall clock. ``frames_to_seconds`` gives the time since label 00:00:00:00 at the true rate.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from fractions import Fraction

from mamma_kit.core.errors import UserError

# true frame rates by name; the nominal (label) rate is the rounded value
STANDARD_RATES: dict[str, Fraction] = {
    "23.976": Fraction(24000, 1001), "24": Fraction(24), "25": Fraction(25),
    "29.97": Fraction(30000, 1001), "30": Fraction(30), "47.952": Fraction(48000, 1001), "48": Fraction(48),
    "50": Fraction(50), "59.94": Fraction(60000, 1001), "60": Fraction(60),
}


def rate_fraction(fps: float | str | Fraction) -> Fraction:
    """A frame rate as an exact fraction (23.976 -> 24000/1001, 29.97 -> 30000/1001, ...)."""
    if isinstance(fps, Fraction):
        return fps
    f = float(fps)
    for r in STANDARD_RATES.values():
        if abs(float(r) - f) < 2e-3:
            return r
    return Fraction(f).limit_denominator(1001)


def nominal_rate(fps: float | Fraction) -> int:
    return int(round(float(fps)))


@dataclass(frozen=True)
class Timecode:
    hours: int
    minutes: int
    seconds: int
    frames: int
    drop_frame: bool = False

    def __str__(self) -> str:
        sep = ";" if self.drop_frame else ":"
        return f"{self.hours:02d}:{self.minutes:02d}:{self.seconds:02d}{sep}{self.frames:02d}"


_TC = re.compile(r"^\s*(\d{1,2})[:;.](\d{1,2})[:;.](\d{1,2})([:;.])(\d{1,3})\s*$")


def parse_timecode(text: str) -> Timecode:
    m = _TC.match(str(text))
    if not m:
        raise UserError(f"'{text}' is not a timecode", "write it as HH:MM:SS:FF (HH:MM:SS;FF for drop-frame)")
    h, mi, s, sep, f = m.groups()
    return Timecode(int(h), int(mi), int(s), int(f), drop_frame=sep in ";.")


def _drop_per_minute(nominal: int) -> int:
    return 2 * nominal // 30  # 2 labels at 29.97, 4 at 59.94


def timecode_to_frames(tc: Timecode | str, fps: float | Fraction) -> int:
    """Frame count since 00:00:00:00 for a label at the given rate (drop-frame aware)."""
    if isinstance(tc, str):
        tc = parse_timecode(tc)
    nom = nominal_rate(fps)
    n = ((tc.hours * 60 + tc.minutes) * 60 + tc.seconds) * nom + tc.frames
    if tc.drop_frame:
        total_minutes = tc.hours * 60 + tc.minutes
        n -= _drop_per_minute(nom) * (total_minutes - total_minutes // 10)
    return n


def frames_to_timecode(n: int, fps: float | Fraction, drop_frame: bool = False) -> Timecode:
    """Inverse of :func:`timecode_to_frames` (wraps at 24 h)."""
    nom = nominal_rate(fps)
    n = int(n)
    if drop_frame:
        d = _drop_per_minute(nom)
        per10 = nom * 600 - 9 * d  # frames in ten minutes
        per1 = nom * 60 - d        # frames in a dropped minute
        tens, rem = divmod(n, per10)
        if rem > d:
            n += 9 * d * tens + d * ((rem - d) // per1)
        else:
            n += 9 * d * tens
    f = n % nom
    s = (n // nom) % 60
    m = (n // (nom * 60)) % 60
    h = (n // (nom * 3600)) % 24
    return Timecode(h, m, s, f, drop_frame)


def frames_to_seconds(n, fps: float | Fraction):
    """Time of frame count ``n`` since 00:00:00:00 at the true rate (works on arrays)."""
    r = rate_fraction(fps)
    return n * (r.denominator / r.numerator)


def timecode_to_seconds(tc: Timecode | str, fps: float | Fraction) -> float:
    return float(frames_to_seconds(timecode_to_frames(tc, fps), fps))
