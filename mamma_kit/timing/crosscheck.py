"""Clocks checked against the people's motion, whichever sync method set them.

With every camera's keypoints already on the reference clock (timing.toml applied), a right sync
leaves every camera pair's motion offset (motion.pair_offset: the people paired across the two
views by their epipolar distance at each whole-frame lag up to ``max_lag_s``, then the sub-frame
minimum) near 0. A camera is off when all its pairs put it the same amount away (OFF_PERIODS frame
periods or more, within AGREE_PERIODS of their median, or half of it: slow motion leaves a pair's
minimum shallow, e.g. 0.26-0.37 s for the demo with one clock 0.3 s off) while the pairs among the
other cameras agree with 0 (within AGREE_PERIODS). With two cameras neither can be named, so nothing
is said. A pair is left out where its minimum is no minimum (the residual CONTRAST_S away is as low:
people paired wrongly in a crowd) or where the two views share too few observations.

The fit uses this on its keypoints: a fit absorbs a late view (its bodies bend towards it and every
view's reprojection error stays small), the pairs' motion does not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.timing.motion import MIN_OBSERVATIONS, View, pair_offset, warnings_off

OFF_PERIODS = 3.0  # an offset under this many frame periods is within what motion can tell here
AGREE_PERIODS = 2.0  # the demo's pairs, synced by LTC, lie within 1.6 periods of 0
MAX_LAG_S = 0.5


@dataclass
class ClockOff:
    """A camera whose clock the others' motion puts ``offset_s`` away (add it to its reference times)."""

    camera: str
    offset_s: float
    pairs_s: dict[str, float]  # other camera -> this camera's offset from that pair
    others_s: float  # the largest |offset| among the pairs of the other cameras


def pair_offsets(views: dict[str, View], max_lag_s: float = MAX_LAG_S) -> dict[tuple[str, str], float]:
    """(a, b) -> b's offset from a's (t_ref = t_b + offset), for the pairs whose motion determines it."""
    names = list(views)
    out = {}
    with warnings_off():
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                o, _, d = pair_offset(views[a], views[b], max_lag_s)
                if d["track_pairs"] and d["observations"] >= MIN_OBSERVATIONS and d["contrast"] > 0:
                    out[(a, b)] = o
    return out


def clocks_off(points: dict, max_lag_s: float = MAX_LAG_S) -> list[ClockOff]:
    """The cameras whose clock disagrees with the others' (module doc), from BlazePose's 33 points:
    ``points`` camera name -> (Camera, times_t on the reference clock, xy_tkj2 px, visibility_tkj,
    valid_tk) per frame and track (or person)."""
    with warnings_off():  # a frame without the person: an all-NaN height, as wanted
        views = {n: View.from_points(cam, times_t, xy, vis, valid)
                 for n, (cam, times_t, xy, vis, valid) in points.items() if valid.any()}
    if len(views) < 3:
        return []
    period = min(v.period for v in views.values())
    pairs = pair_offsets(views, max_lag_s)
    out = []
    for c in views:
        mine = {(b if a == c else a): (o if b == c else -o) for (a, b), o in pairs.items() if c in (a, b)}
        rest = [abs(o) for (a, b), o in pairs.items() if c not in (a, b)]
        if len(mine) < 2 or not rest:
            continue
        m = float(np.median(list(mine.values())))
        spread = max(abs(o - m) for o in mine.values())
        if abs(m) >= OFF_PERIODS * period and spread <= max(AGREE_PERIODS * period, 0.5 * abs(m)) and \
                max(rest) <= AGREE_PERIODS * period:
            out.append(ClockOff(c, m, mine, max(rest)))
    return out
