"""Two people who cross and whom every view's tracker exchanged: their limb lengths tell them apart
(matching/stature.py), and people of one build, or whose lengths wander, are left alone."""

from __future__ import annotations

import numpy as np
from conftest import make_ring_rig

from mamma_kit.matching.pairs import ViewTracks
from mamma_kit.matching.sources import ViewSource
from mamma_kit.matching.stature import exchange_by_stature

FPS, T, MEET = 20.0, 60, 42


def _keypoints(scale: float, at_3: np.ndarray) -> np.ndarray:
    """(33, 3) BlazePose points of a standing body of limb length 1.37 m x ``scale`` at ``at_3``:
    shoulders, hips, knees and ankles where they are; the other points at the neck."""
    X = np.tile([0.0, 0.0, 1.45], (33, 1))
    for side, sx in ((0, 0.18), (1, -0.18)):
        for j, (x, z) in zip((11, 23, 25, 27), ((sx, 1.45), (sx / 2, 0.95), (sx / 2, 0.5), (sx / 2, 0.08))):
            X[j + side] = [x, 0.0, z]
    return X * [1.0, 1.0, scale] + at_3


def _crossing(scales=(1.0, 0.86), noise_m: float = 0.0, seed: int = 0):
    """Two people walking past each other (0.3 m apart in y, 1.3 m/s); every view's track 0 follows
    person 0 until they meet (frame MEET), then person 1, and track 1 the other way."""
    rng = np.random.default_rng(seed)
    rig = make_ring_rig(4, radius=4.0)
    s = (np.arange(T) - MEET) / FPS * 1.3
    paths = [np.c_[s, np.zeros(T), np.zeros(T)], np.c_[-s, np.full(T, 0.3), np.zeros(T)]]
    X = np.stack([[_keypoints(scales[p] * (1 + noise_m * rng.standard_normal()), paths[p][t]) for t in range(T)]
                  for p in range(2)])  # (2, T, 33, 3)
    who = np.where(np.arange(T)[:, None] < MEET, [0, 1], [1, 0])  # (T, tracks): the person each track shows
    times = np.arange(T) / FPS
    views, person = [], {}
    for cam in rig:
        xy = np.stack([cam.project(X[who[t], t].reshape(-1, 3)).reshape(2, 33, 2) for t in range(T)])
        vt = ViewTracks.from_arrays(cam.name, np.arange(2), xy, np.ones((T, 2), bool), np.ones((T, 2, 33)), cam,
                                    times, 0.5, 8.0)
        views.append(ViewSource.in_memory(vt))
        person[cam.name] = np.tile([0, 1], (T, 1))  # the match followed the tracks
    return views, person, np.array([0.0, 1.5, 3.1])


def test_exchanged_people_get_their_labels_back_where_they_met():
    views, person, edges = _crossing()
    out, done = exchange_by_stature(person, views, views, edges)
    assert len(done) == 1 and done[0]["persons"] == [0, 1], done
    assert abs(done[0]["lengths_m"][0] - done[0]["lengths_m"][1]) > 0.15
    for name, a in out.items():
        assert (a[:MEET - 2] == [0, 1]).all() and (a[MEET + 2:] == [1, 0]).all(), (name, a[MEET - 5:MEET + 5])


def test_people_of_one_build_or_whose_lengths_wander_are_left_alone():
    for kw in ({"scales": (1.0, 0.97)}, {"noise_m": 0.12}):
        views, person, edges = _crossing(**kw)
        out, done = exchange_by_stature(person, views, views, edges)
        assert done == [] and all((out[n] == person[n]).all() for n in person), (kw, done)
