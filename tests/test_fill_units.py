"""The fill's geometry and bookkeeping on exact data: where a view lacks a person the others see,
the projected skeleton is the true one; new tracks join a view's own without disturbing them."""

from __future__ import annotations

import numpy as np

from conftest import make_ring_rig, walking_people
from mamma_kit.core.tracks import KeypointTracks, LandmarkTracks, MaskTracks, append_tracks
from mamma_kit.filling.gaps import find_gaps, persons_per_frame


def test_a_missing_person_projects_where_they_are():
    """Three people seen by four cameras; in cam0 person 1 has no track in frames 3-6: those are the
    gaps (no other), and the skeleton triangulated from the other views' exact points projects onto
    the true one (to 1e-6 px)."""
    rig = make_ring_rig(4)
    T, P = 10, 3
    X_tpj3 = walking_people(np.random.default_rng(1), P, T, L=33)
    times = np.arange(T) / 30.0
    others = {}
    for cam in rig:
        xy = cam.project(X_tpj3.reshape(-1, 3)).reshape(T, P, 33, 2)
        others[cam.name] = (times, xy, np.ones((T, P, 33)))  # each person's points in that view
    covered = np.ones((T, P), bool)
    covered[3:7, 1] = False
    g = find_gaps("cam0", times, covered, others, rig, [0, 1, 2])
    assert g.frame_g.tolist() == [3, 4, 5, 6] and (g.person_g == 1).all() and (g.views_g == 3).all()
    truth = rig["cam0"].project(X_tpj3[3:7, 1].reshape(-1, 3)).reshape(4, 33, 2)
    np.testing.assert_allclose(g.xy_g332, truth, atol=1e-6)


def test_persons_per_frame_names_the_track_showing_each_person():
    person_tk = np.array([[0, 1, -1], [1, 1, 0], [-1, -1, -1]])
    present_tk = np.array([[True, True, False], [True, False, True], [True, True, True]])
    out = persons_per_frame(person_tk, present_tk, [0, 1])
    assert out.tolist() == [[0, 1], [2, 0], [-1, -1]]


def test_appended_tracks_keep_both_sets_whole():
    """Masks, keypoints and landmarks of new tracks appended to a view's own: every mask decodes as
    before, arrays keep their rows, ids follow."""
    rng = np.random.default_rng(0)
    T, W, H = 5, 40, 30
    times = np.arange(T) / 10.0

    def masks(ids, seed):
        r = np.random.default_rng(seed)
        m = {(t, k): r.random((H, W)) > 0.7 for t in range(T) for k in range(len(ids)) if (t + k) % 2 == 0}
        return MaskTracks.from_masks("c", (W, H), times, np.asarray(ids), m), m

    a, ma = masks([0, 1], 1)
    b, mb = masks([5], 2)
    ab = append_tracks(a, b)
    assert ab.track_ids.tolist() == [0, 1, 5]
    for (t, k), m in ma.items():
        np.testing.assert_array_equal(ab.mask(t, k), m)
    for (t, k), m in mb.items():
        np.testing.assert_array_equal(ab.mask(t, 2 + k), m)
    assert not ab.present[1, 2] and ab.present[0, 2]
    ka, kb = KeypointTracks.empty("c", (W, H), times, [0, 1]), KeypointTracks.empty("c", (W, H), times, [5])
    kb.xy[:] = rng.random(kb.xy.shape)
    kab = append_tracks(ka, kb)
    assert kab.xy.shape == (T, 3, 33, 2) and kab.hand_xy.shape[1] == 3
    np.testing.assert_array_equal(kab.xy[:, 2], kb.xy[:, 0])
    la = LandmarkTracks.empty("c", (W, H), times, [0, 1], 8)
    lb = LandmarkTracks.empty("c", (W, H), times, [5], 8)
    lb.valid[:] = True
    lab = append_tracks(la, lb)
    assert lab.valid[:, 2].all() and not lab.valid[:, :2].any()


def test_a_lone_find_makes_no_track_and_runs_split_at_long_gaps():
    """Finds of one person in frames 0, 1, 2, 9, 20 and 21 (and another person's in frame 5 only):
    runs of finds at most MAX_RUN_GAP apart, each a track if it has MIN_FOUND finds; the lone finds
    in frames 9 and 5 (a glimpse) make none."""
    from mamma_kit.filling.look import Found
    from mamma_kit.filling.stage import MAX_RUN_GAP, MIN_FOUND, runs_of

    assert MAX_RUN_GAP < 7 and MIN_FOUND == 2

    def fd(frame, person):
        return Found(frame, person, (), np.zeros((33, 5)), 0.9, 0.05)

    runs = runs_of([fd(f, 3) for f in (21, 0, 9, 1, 2, 20)] + [fd(5, 4)])
    assert [(p, [x.frame for x in r]) for p, r in runs] == [(3, [0, 1, 2]), (3, [20, 21])]
