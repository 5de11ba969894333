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


def _random_landmarks(T=40, K=4, L=16, seed=0):
    rng = np.random.default_rng(seed)
    lt = LandmarkTracks.empty("cam1", (640, 480), np.arange(T) / 30, np.array([3, 5, 9, 11])[:K], L, "set", "src")
    lt.valid[:] = rng.random((T, K)) < 0.4
    t, k = np.nonzero(lt.valid)
    lt.xy[t, k] = rng.uniform(0, 400, (len(t), L, 2))
    lt.visibility[t, k] = rng.random((len(t), L))
    lt.visibility[2, 1] = 0.25  # a cell with data but not valid is kept too
    return lt


def _same(a, b):
    from dataclasses import fields

    for f in fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.shape == y.shape and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), f.name
        else:
            assert x == y, f.name


def test_track_files_are_rows_that_read_back_as_the_arrays(tmp_path):
    """A file holds the occupied (frame, track) cells only; whole, windows and chosen columns read
    back as the frames x tracks arrays they came from."""
    import zipfile

    from mamma_kit.core.trackrows import TrackFile

    lt = _random_landmarks()
    lt.save(tmp_path / "l.npz")
    with zipfile.ZipFile(tmp_path / "l.npz") as z:
        assert "row_frame.npy" in z.namelist()
    n_rows = int(lt.valid.sum()) + (0 if lt.valid[2, 1] else 1)
    with TrackFile(tmp_path / "l.npz", LandmarkTracks) as tf:
        assert len(tf.row_frame) == n_rows
        _same(tf.window(), lt)
        w = tf.window(10, 25)
        assert np.array_equal(w.xy, lt.xy[10:25], equal_nan=True) and np.array_equal(w.valid, lt.valid[10:25])
        w = tf.window(5, 30, cols=np.array([2, 0]))
        assert w.track_ids.tolist() == [9, 3] and np.array_equal(w.xy, lt.xy[5:30][:, [2, 0]], equal_nan=True)
        back = tf.window(0, 8)  # going back re-reads from the start
        assert np.array_equal(back.visibility, lt.visibility[:8])
        assert np.array_equal(tf.valid_tk(), lt.valid)
        assert tf.columns_in(10, 25).tolist() == sorted(set(np.nonzero(tf.window(10, 25).valid | (
            tf.window(10, 25).visibility.sum(-1) > 0))[1].tolist()))


def test_older_frames_by_tracks_files_read_the_same(tmp_path):
    from mamma_kit.core.io import write_npz
    from mamma_kit.core.trackrows import TrackFile

    lt = _random_landmarks(seed=1)
    write_npz(tmp_path / "old.npz", camera=np.array(lt.camera), image_size=np.asarray(lt.image_size),
              frame_times=lt.frame_times, track_ids=lt.track_ids, valid=lt.valid, xy=lt.xy, sigma=lt.sigma,
              visibility=lt.visibility, contact=lt.contact, floor_contact=lt.floor_contact,
              landmark_set=np.array("set"), source=np.array("src"), producer=np.array("{}"))
    _same(LandmarkTracks.load(tmp_path / "old.npz"), lt)
    with TrackFile(tmp_path / "old.npz", LandmarkTracks) as tf:
        assert np.array_equal(tf.window(7, 19).xy, lt.xy[7:19], equal_nan=True)


def test_row_writer_streams_rows_in_order_and_refuses_them_out_of_order(tmp_path):
    import pytest

    from mamma_kit.core.trackrows import RowWriter

    lt = _random_landmarks(seed=2)
    header = {k: getattr(lt, k) for k in ("camera", "image_size", "frame_times", "track_ids", "landmark_set",
                                          "source", "producer")}
    t, k = np.nonzero(lt.valid)
    with RowWriter(tmp_path / "w.npz", LandmarkTracks, header, 16) as w:
        for a in range(0, len(t), 5):
            s = slice(a, a + 5)
            w.append(t[s], k[s], valid=lt.valid[t[s], k[s]], xy=lt.xy[t[s], k[s]],
                     visibility=lt.visibility[t[s], k[s]])
        with pytest.raises(ValueError):
            w.append(t[:1], k[:1], valid=np.ones(1, bool))
        w.close()
    back = LandmarkTracks.load(tmp_path / "w.npz")
    assert np.array_equal(back.valid, lt.valid)
    assert np.array_equal(back.xy, np.where(lt.valid[..., None, None], lt.xy, np.nan), equal_nan=True)
    assert not list(tmp_path.glob(".*"))  # no temporary file left
    with pytest.raises(RuntimeError), RowWriter(tmp_path / "x.npz", LandmarkTracks, header, 16) as w:
        w.append(t[:2], k[:2], valid=np.ones(2, bool))
        raise RuntimeError("stopped")
    assert not (tmp_path / "x.npz").exists() and not list(tmp_path.glob(".*"))


def test_a_camera_with_no_tracks_or_no_frames_saves_and_reads_back(tmp_path):
    """A board-only view has no tracks; an empty take has no frames: both still write a file."""
    from mamma_kit.core.trackrows import TrackFile

    for T, ids in ((5, np.zeros(0, int)), (0, np.array([1, 2]))):
        lt = LandmarkTracks.empty("cam0", (64, 48), np.arange(T) / 30, ids, 8, "set", "src")
        lt.save(tmp_path / "e.npz")
        with TrackFile(tmp_path / "e.npz", LandmarkTracks) as tf:
            back = tf.window()
        assert back.xy.shape == (T, len(ids), 8, 2) and not back.valid.any()
