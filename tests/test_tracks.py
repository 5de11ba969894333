"""Track files: RLE round trips (hypothesis) and masks/landmarks save/load."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mamma_kit.core.tracks import LandmarkTracks, MaskTracks, rle_area, rle_decode, rle_encode


@settings(max_examples=60, deadline=None)
@given(m=arrays(bool, st.tuples(st.integers(1, 20), st.integers(1, 20))))
def test_rle_roundtrip(m):
    c = rle_encode(m)
    assert np.array_equal(rle_decode(c, (m.shape[1], m.shape[0])), m)
    assert rle_area(c) == m.sum()


def test_mask_tracks_save_load(tmp_path):
    h, w = 30, 40
    m = np.zeros((h, w), bool)
    m[5:10, 8:20] = True
    mt = MaskTracks.from_masks("cam0", (w, h), np.array([0.0, 0.033]), np.array([3, 7]), {(0, 1): m, (1, 0): ~m})
    mt.save(tmp_path / "m.npz")
    back = MaskTracks.load(tmp_path / "m.npz")
    assert np.array_equal(back.mask(0, 1), m) and back.mask(0, 0) is None
    assert back.boxes[0, 1].tolist() == [8, 5, 20, 10]
    assert back.present.tolist() == [[False, True], [True, False]]
    assert back.area(1, 0) == (~m).sum()


def test_landmark_tracks_save_load(tmp_path):
    lt = LandmarkTracks.empty("cam1", (640, 480), np.arange(3) / 30, np.array([0, 1]), 512, "test", "gt")
    lt.valid[1, 0] = True
    lt.xy[1, 0] = np.random.default_rng(0).uniform(0, 400, (512, 2))
    lt.save(tmp_path / "l.npz")
    back = LandmarkTracks.load(tmp_path / "l.npz")
    assert back.valid.tolist() == lt.valid.tolist() and np.allclose(back.xy[1, 0], lt.xy[1, 0])
    assert back.landmark_set == "test" and back.n_landmarks == 512
