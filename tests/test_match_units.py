"""Matching pieces: tracklet epipolar distances, grouping constraints, identities.json round trip."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import landmark_view, make_ring_rig, walking_people
from mamma_kit.core.errors import UserError
from mamma_kit.core.identities import Identities, read_identities, write_identities
from mamma_kit.matching.grouping import Node, group_tracks
from mamma_kit.matching.match import match_views
from mamma_kit.matching.pairs import ViewTracks, pair_distances


def test_exact_correspondences_have_zero_distance_and_others_do_not():
    rng = np.random.default_rng(0)
    rig = make_ring_rig(3, dist=[0.05, -0.02, 0, 0, 0])
    X = walking_people(rng, 3, 10)
    times = np.arange(10) / 30
    va = ViewTracks.from_landmarks(landmark_view(rig[0], X, times), rig[0], times)
    vb = ViewTracks.from_landmarks(landmark_view(rig[1], X, times, perm=np.array([2, 0, 1])), rig[1], times)
    r = pair_distances(va, vb)
    # track i of a is person i; track j of b is person perm[j]
    for i in range(3):
        j = [2, 0, 1].index(i)
        assert r.distance[i, j] < 1e-6
        assert r.shared_landmarks[i, j] == 400 and r.shared_frames[i, j] == 10
    right = np.array([2, 0, 1])[None, :] == np.arange(3)[:, None]  # b's track j shows person perm[j]
    assert r.distance[right].max() < 1e-6 and r.distance[~right].min() > 0.01


def test_low_visibility_probabilities_keep_the_more_visible_half():
    """A network whose visibility never reaches 0.5 (short training) still matches: each detection
    keeps its more visible half, and landmarks above the threshold always count."""
    rng = np.random.default_rng(1)
    rig = make_ring_rig(2)
    X = walking_people(rng, 2, 6)
    times = np.arange(6) / 30
    la, lb = landmark_view(rig[0], X, times), landmark_view(rig[1], X, times, perm=np.array([1, 0]))
    for lt in (la, lb):
        lt.visibility[:] = rng.uniform(0.2, 0.4, lt.visibility.shape)
    va, vb = ViewTracks.from_landmarks(la, rig[0], times), ViewTracks.from_landmarks(lb, rig[1], times)
    assert va.vis_tkl.sum(-1).min() == 20  # half of 40 landmarks per detection
    r = pair_distances(va, vb)
    assert r.shared_landmarks[0, 1] > 0 and r.distance[0, 1] < 1e-6 < r.distance[0, 0]
    la.visibility[:] = 0.9
    assert ViewTracks.from_landmarks(la, rig[0], times).vis_tkl.all()


@settings(max_examples=15, deadline=None)
@given(st.floats(0.25, 4.0))
def test_distance_is_resolution_independent(scale):
    """Distances in person heights do not change when both images are resized."""
    rng = np.random.default_rng(1)
    rig = make_ring_rig(2)
    X = walking_people(rng, 2, 5)
    times = np.arange(5) / 30.0
    base = pair_distances(*[ViewTracks.from_landmarks(landmark_view(c, X, times, noise=0.0), c, times) for c in rig])
    cams = [c.scaled(scale) for c in rig]
    scaled = pair_distances(*[ViewTracks.from_landmarks(landmark_view(c, X, times), c, times) for c in cams])
    assert np.allclose(base.distance, scaled.distance, atol=1e-6)


def test_unsynchronised_frames_are_interpolated():
    """View b's frames fall between a's: linear interpolation keeps moving people consistent."""
    rng = np.random.default_rng(2)
    rig = make_ring_rig(2)
    T = 20
    ta = np.arange(T) / 30.0
    tb = ta + 0.5 / 30  # half a frame later
    X = walking_people(rng, 2, 2 * T + 2)
    # motion sampled at 60 Hz: a sees even samples, b odd ones
    va = ViewTracks.from_landmarks(landmark_view(rig[0], X[0:2 * T:2], ta), rig[0], ta)
    vb = ViewTracks.from_landmarks(landmark_view(rig[1], X[1:2 * T + 1:2], tb), rig[1], tb)
    r = pair_distances(va, vb)
    assert r.distance[0, 0] < 1e-3 and r.distance[1, 1] < 1e-3


def test_grouping_refuses_a_chain_union_find_would_make():
    """A wrong strong edge a0-b1 would chain persons 0 and 1 under union-find over edges; the
    average linkage of the groups it would merge is low, so it is rejected."""
    # views 0, 1, 2, two people each: node = 2 * view + person
    nodes = [Node(v, p, np.ones(5, bool)) for v in range(3) for p in range(2)]
    N = len(nodes)
    A = np.zeros((N, N))

    def s(x, y, a):
        A[x, y] = A[y, x] = a

    s(0, 2, 0.9), s(2, 4, 0.9), s(0, 4, 0.9)  # person 0 in views 0, 1, 2
    s(1, 3, 0.9), s(3, 5, 0.9), s(1, 5, 0.9)  # person 1
    s(4, 3, 0.85)  # a wrong, strong v2:p0 - v1:p1 edge, stronger than ...
    s(4, 2, 0.3)  # ... the weak right one in that pair
    ev = np.ones((N, N), bool)
    g = group_tracks(nodes, A, ev, [(0, 1), (0, 2), (1, 2)], min_affinity=0.25)
    groups = sorted(sorted(x) for x in g.groups)
    assert groups == [[0, 2, 4], [1, 3, 5]]
    # no group holds two tracks of one view
    for grp in g.groups:
        views = [nodes[i].view for i in grp]
        assert len(views) == len(set(views))


def test_two_tracks_of_one_view_share_a_person_only_if_they_never_coexist():
    pres_a = np.r_[np.ones(5, bool), np.zeros(5, bool)]
    nodes = [Node(0, 0, pres_a), Node(0, 1, ~pres_a), Node(1, 0, np.ones(10, bool)),
             Node(0, 2, np.ones(10, bool))]
    A = np.zeros((4, 4))
    for x in (0, 1, 3):
        A[x, 2] = A[2, x] = 0.8
    ev = np.ones((4, 4), bool)
    g = group_tracks(nodes, A, ev, [(0, 1)], min_affinity=0.25)
    grp = next(x for x in g.groups if 2 in x)
    assert 3 not in grp or (0 not in grp and 1 not in grp)  # track 2 co-exists with both
    # without the co-existing track 2 both halves join
    g = group_tracks(nodes[:3], A[:3, :3], ev[:3, :3], [(0, 1)], min_affinity=0.25)
    assert sorted(sorted(x) for x in g.groups) == [[0, 1, 2]]


def test_many_views_and_people_scale():
    """16 cameras, 7 people, noisy landmarks, per-view random track ids: all grouped right."""
    rng = np.random.default_rng(3)
    rig = make_ring_rig(16, size=(640, 480))
    X = walking_people(rng, 7, 12, L=60)
    times = np.arange(12) / 30.0
    views, truth = [], {}
    for c in rig:
        perm = rng.permutation(7)
        lt = landmark_view(c, X, times, perm=perm, noise=1.0, rng=rng)
        lt.track_ids = rng.choice(1000, 7, replace=False)
        views.append(ViewTracks.from_landmarks(lt, c, times))
        for k in range(7):
            truth[(c.name, int(lt.track_ids[k]))] = int(perm[k])
    ident = match_views(views)
    for p in ident.person_ids:
        members = {truth[k] for k in ident.tracks_of(p)}
        assert len(members) == 1
        assert len(ident.views_of(p)) == 16


def test_identities_round_trip(tmp_path):
    ident = Identities(["a", "b"], {"a": {3: 0, 4: 1}, "b": {7: 0}}, track_frames={("a", 3): 10})
    path = write_identities(tmp_path / "identities.json", ident)
    back = read_identities(path)
    assert back.person_of("a", 4) == 1 and back.person_of("b", 7) == 0 and back.person_of("b", 9) is None
    assert back.tracks_of(0) == [("a", 3), ("b", 7)]
    assert back.persons()[0]["views"] == 2
    (tmp_path / "bad.json").write_text('{"format": "other"}')
    with pytest.raises(UserError, match="not a mamma-kit identities file"):
        read_identities(tmp_path / "bad.json")
    with pytest.raises(UserError, match="run `mamma-kit match"):
        read_identities(tmp_path / "missing.json")
