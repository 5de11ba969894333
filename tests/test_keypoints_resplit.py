"""keypoints/resplit.py: touching people's masks re-split by their skeletons.

Two stick people drawn from known 33-point skeletons hold hands; the "tracker" cut between them
falls on the wrong arm (the left person's forearm and hand go to the right person). The re-split
must give those pixels back, leave each person's own body alone, and change nothing where people
do not touch or a skeleton is missing.
"""

from __future__ import annotations

import cv2
import numpy as np

from mamma_kit.keypoints.resplit import LIMBS, TORSO, person_size, split_touching

H, W = 240, 320


def skeleton(cx: float, reach: float) -> np.ndarray:
    """(33, 5) points of an upright person 180 px tall centred at x = cx, its right arm (BlazePose
    12-14-16, on the image's +x side when reach > 0) held out sideways by ``reach`` px."""
    p = np.full((33, 5), np.nan)
    y_sh, y_hip, y_knee, y_ank = 60.0, 130.0, 170.0, 210.0
    pts = {0: (cx, 35), 7: (cx - 8, 35), 8: (cx + 8, 35), 11: (cx - 18, y_sh), 12: (cx + 18, y_sh),
           23: (cx - 12, y_hip), 24: (cx + 12, y_hip), 25: (cx - 12, y_knee), 26: (cx + 12, y_knee),
           27: (cx - 12, y_ank), 28: (cx + 12, y_ank), 29: (cx - 14, y_ank + 4), 30: (cx + 14, y_ank + 4),
           31: (cx - 6, y_ank + 6), 32: (cx + 6, y_ank + 6),
           13: (cx - 24, 95), 15: (cx - 26, 125), 17: (cx - 27, 132), 19: (cx - 25, 133), 21: (cx - 23, 130)}
    s = np.sign(reach)
    pts.update({14: (cx + 18 + 0.5 * reach, y_sh + 5), 16: (cx + 18 + reach, y_sh + 10),
                18: (cx + 18 + reach + 6 * s, y_sh + 12), 20: (cx + 18 + reach + 7 * s, y_sh + 9),
                22: (cx + 18 + reach + 4 * s, y_sh + 6)})
    for k, (x, y) in pts.items():
        p[k] = (x, y, 0.0, 0.95, 0.99)
    return p


def draw(p: np.ndarray) -> np.ndarray:
    """The person's silhouette: its limbs a little thicker than resplit draws them."""
    m = np.zeros((H, W), np.uint8)
    size = person_size(p)
    for (a, b), r in LIMBS:
        if np.isfinite(p[[a, b], :2]).all():
            cv2.line(m, tuple(np.round(p[a, :2]).astype(int)), tuple(np.round(p[b, :2]).astype(int)), 1,
                     max(1, int(round(2.6 * r * size))))
    cv2.fillPoly(m, [np.round(p[list(TORSO), :2]).astype(np.int32)], 1)
    return m > 0


def holding_hands():
    a, b = skeleton(110, 30), skeleton(210, -30)  # right arms reach towards each other: hands meet at x ~ 160
    ga, gb = draw(a), draw(b)
    gb &= ~ga  # a's hand in front
    # the tracker's cut: a vertical line left of the hands gives a's forearm and hand to b
    cut = np.zeros((H, W), bool)
    cut[:, :145] = True
    return a, b, ga, gb, ga & cut, (ga & ~cut) | gb


def test_the_wrong_forearm_goes_back_to_its_person():
    a, b, ga, gb, ta, tb = holding_hands()
    wrong = ga & tb
    assert wrong.sum() > 80  # the setup: a forearm and hand on the wrong side
    out = split_touching({0: ta, 1: tb}, {0: a, 1: b})
    na, nb = out[0], out[1]
    assert not (na & nb).any()
    assert np.array_equal(na | nb, ta | tb)  # pixels change hands; none appear or vanish
    # the wrongly cut forearm is a's again (where the two hands overlap, the skeletons cannot tell
    # whose pixel is in front: those keep the tracker's answer), and b keeps its own body
    forearm = wrong.copy()
    forearm[:, int(a[16, 0]) - 2:] = False
    assert forearm.sum() > 40
    assert (na & forearm).sum() >= 0.9 * forearm.sum()
    assert (na & wrong).sum() >= 0.6 * wrong.sum()
    assert (nb & gb).sum() >= 0.97 * gb.sum()
    iou = lambda m, g: (m & g).sum() / (m | g).sum()  # noqa: E731
    assert iou(ta, ga) < 0.97 and iou(na, ga) > 0.98


def test_apart_alone_or_without_a_skeleton_nothing_changes():
    a, b = skeleton(80, 20), skeleton(240, -20)
    ma, mb = draw(a), draw(b)
    out = split_touching({0: ma, 1: mb}, {0: a, 1: b})  # apart
    assert out[0] is ma and out[1] is mb
    _, _, _, _, ta, tb = holding_hands()
    out = split_touching({0: ta, 1: tb}, {0: a, 1: None})  # one person's points missing
    assert out[0] is ta and out[1] is tb
    unsure = a.copy()
    unsure[:, 3] = 0.1  # BlazePose unsure of every point: no body drawn, nothing decided
    out = split_touching({0: ta, 1: tb}, {0: unsure, 1: b})
    assert out[0] is ta and out[1] is tb
    assert split_touching({0: ta}, {0: a})[0] is ta


def test_person_size_from_legs_or_torso():
    p = skeleton(100, 30)
    assert abs(person_size(p) - (70 + 40 + 40)) < 2  # shoulder-hip-knee-ankle down each side
    legs_hidden = p.copy()
    legs_hidden[[25, 26, 27, 28], 3] = 0.0
    assert 100 < person_size(legs_hidden) < 200
    assert person_size(np.full((33, 5), np.nan)) is None


def test_rounds_from_the_setting():
    import pytest

    from mamma_kit.core.errors import UserError
    from mamma_kit.keypoints.stage import RESPLIT_ROUNDS, resplit_rounds

    assert resplit_rounds(True) == RESPLIT_ROUNDS > 0 and resplit_rounds(False) == 0 and resplit_rounds(3) == 3
    for bad in ("yes", -1, 1.5):
        with pytest.raises(UserError, match="rounds"):
            resplit_rounds(bad)
