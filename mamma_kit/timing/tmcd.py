"""tmcd: the QuickTime timecode track's start timecode as a whole-frame clock.

The track labels the first video frame; later frames follow the camera's own clock. So
t_tc = t_cam - t_first_frame + seconds(start timecode): an offset to the nearest frame and
no drift. Confidence is low by design (half a frame of uncertainty, no drift).
"""

from __future__ import annotations

from dataclasses import dataclass

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.timecode import STANDARD_RATES, parse_timecode, rate_fraction, timecode_to_seconds

CONFIDENCE = 0.3


@dataclass
class TmcdClock:
    clock: ClockModel   # camera time -> timecode time
    timecode: str
    fps: float
    fps_name: str


def tmcd_clock(timecode: str, video_fps: float, first_frame_s: float) -> TmcdClock:
    """The clock implied by a start timecode on a video of nominal rate ``video_fps``."""
    tc = parse_timecode(timecode)
    # VFR phone videos report a mean rate near, not at, a standard one: snap within 2 %
    from fractions import Fraction

    cands = list(STANDARD_RATES.values()) + [Fraction(max(1, round(video_fps)))]
    std = min(cands, key=lambda r: abs(float(r) - video_fps))
    rate = std if abs(float(std) - video_fps) < 0.02 * video_fps else rate_fraction(video_fps)
    if tc.drop_frame:
        rate = min((r for r in STANDARD_RATES.values() if r.denominator == 1001),
                   key=lambda r: abs(float(r) - float(rate)))
    start = timecode_to_seconds(tc, rate)
    name = next((k for k, v in STANDARD_RATES.items() if v == rate), f"{float(rate):.3f}")
    return TmcdClock(ClockModel(start - first_frame_s, 0.0, "tmcd", CONFIDENCE), str(tc), float(rate), name)
