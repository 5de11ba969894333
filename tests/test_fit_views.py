"""fitting/views.py: a view whose keypoints follow the wrong thing is found by the other views'
consensus and set aside; consistent views, noisy ones and two-camera rigs are left alone."""

from __future__ import annotations

import numpy as np

from conftest import make_ring_rig
from mamma_kit.fitting.views import CONSENSUS_POINTS, inconsistent_views


def _people_keypoints(rig, P=2, T=6, seed=0, noise_px=1.5):
    """33 points of P upright people over T frames seen by every camera: xy (C, P, T, 33, 2),
    vis (C, P, T, 33), size (C, P, T) px, and the 3D points (P, T, 33, 3)."""
    rng = np.random.default_rng(seed)
    X = np.zeros((P, T, 33, 3))
    X[..., 2] = rng.uniform(0.1, 1.7, 33)
    X[..., :2] = rng.normal(0, 0.15, (33, 2)) + rng.uniform(-1.0, 1.0, (P, 1, 1, 2))
    xy = rig.project(X) + rng.normal(0, noise_px, (len(rig), P, T, 33, 2))
    size = (np.nanmax(xy, -2) - np.nanmin(xy, -2)).max(-1)
    return xy, np.ones(xy.shape[:-1]), size, X


def test_a_view_reading_the_other_person_is_set_aside():
    rig = make_ring_rig(4)
    xy, vis, size, _ = _people_keypoints(rig)
    assert not inconsistent_views(rig, xy, vis, size, 0.1)[0].any()  # pixel noise alone: nobody
    bad = xy.copy()
    bad[2, 1, 2:5] = xy[2, 0, 2:5]  # cam2 reads person 0's points for person 1 in frames 2-4
    f = inconsistent_views(rig, bad, vis, size, 0.1)[0]
    assert f[2, 1, 2:5].all() and f.sum() == 3
    # three cameras still find it (two agree without it)
    sub = rig.subset(["cam0", "cam1", "cam2"])
    f3 = inconsistent_views(sub, bad[:3], vis[:3], size[:3], 0.1)[0]
    assert f3[2, 1, 2:5].all() and f3.sum() == 3


def test_unseen_points_and_two_camera_rigs_flag_nothing():
    rig = make_ring_rig(4)
    xy, vis, size, _ = _people_keypoints(rig, seed=3)
    bad = xy.copy()
    bad[1, 0, :] += 0.4 * size[1, 0, :, None, None]  # cam1 shifted by 40 % of the person
    vis_few = vis.copy()
    vis_few[1, 0, :, list(CONSENSUS_POINTS)[3:]] = 0  # but it reads only three body points there
    assert not inconsistent_views(rig, bad, vis_few, size, 0.1)[0][1].any()
    assert inconsistent_views(rig, bad, vis, size, 0.1)[0][1, 0].all()
    two = rig.subset(["cam0", "cam1"])
    assert not inconsistent_views(two, bad[:2], vis[:2], size[:2], 0.1)[0].any()  # who is wrong? cannot tell


def test_set_aside_takes_landmarks_only_where_they_follow_the_keypoints_off():
    from mamma_kit.fitting.data import FitData
    from mamma_kit.fitting.views import set_aside_inconsistent

    rig = make_ring_rig(4)
    xy, vis, size, X = _people_keypoints(rig)
    lm_xy = xy[..., :10, :].copy()  # ten landmarks on the same bodies, read right in every view
    xy[3, 0, 1] = xy[3, 1, 1]  # cam3's keypoints for person 0 in frame 1 are person 1's
    C, P, T, L = 4, 2, 6, 10

    def data(lm):
        ones = np.ones((C, P, T, L), np.float32)
        return FitData(rig, {}, "cam0", "cam0", np.arange(T) / 30.0, 30.0, [0, 1], lm.astype(np.float32),
                       np.ones((C, P, T, L, 2), np.float32), ones, 0 * ones, 0 * ones, np.ones((C, P, T), bool),
                       kp_xy=xy.astype(np.float32), kp_vis=vis.astype(np.float32), kp_size=size.astype(np.float32),
                       hand_xy=np.zeros((C, P, T, 42, 2), np.float32), hand_vis=np.ones((C, P, T, 42), np.float32))

    def only_there(a):
        return (a[3, 0, 1] == 0).all() and a.sum() == a.size - a[3, 0, 1].size

    d = data(lm_xy)
    subset = np.arange(L)
    out, summary = set_aside_inconsistent(d, 0.1, subset)
    assert only_there(out.kp_vis) and only_there(out.hand_vis)  # the keypoints go ...
    assert out.vis.all() and summary == {"cam3": {"0": {"keypoints": 1, "landmarks": 0}}}  # ... the landmarks stay
    followed = lm_xy.copy()
    followed[3, 0, 1] = lm_xy[3, 1, 1]  # a keypoint-guided network follows them onto person 1
    out, summary = set_aside_inconsistent(data(followed), 0.1, subset)
    assert only_there(out.vis) and only_there(out.kp_vis)
    assert summary == {"cam3": {"0": {"keypoints": 1, "landmarks": 1}}}
    out, _ = set_aside_inconsistent(d, 0.1)  # no subset to judge them by: the landmarks go too
    assert only_there(out.vis)
    assert d.vis.all() and d.kp_vis.all()  # the input is left as it was
    assert set_aside_inconsistent(d, 0.0) == (d, {})
