"""Units of work per (camera, frame range) for the stages that can split a video (issue 25):
keypoints and landmarks with --unit-frames write the same files as a camera per unit."""

import json

import numpy as np
import pytest
import torch
from test_landmarks_cli import T, ws  # noqa: F401 - the small workspace fixture

from mamma_kit.core.errors import UserError
from mamma_kit.core.executor import frame_ranges
from mamma_kit.core.tracks import KeypointTracks, LandmarkTracks


def test_frame_ranges_cover_the_video_once():
    assert frame_ranges(10, 0) == [(0, 10)] and frame_ranges(10, 10) == [(0, 10)]
    assert frame_ranges(10, 4) == [(0, 4), (4, 8), (8, 10)]
    assert frame_ranges(0, 4) == [(0, 0)]
    with pytest.raises(UserError, match="negative"):
        frame_ranges(10, -1)


def test_frame_ranges_follow_the_environment(monkeypatch):
    monkeypatch.setenv("MAMMA_KIT_UNIT_FRAMES", "3")
    assert frame_ranges(7) == [(0, 3), (3, 6), (6, 7)]
    assert frame_ranges(7, 0) == [(0, 7)]  # an explicit setting wins


def test_landmarks_split_into_frame_ranges_equal_a_camera_per_unit(ws, tmp_path, cli):  # noqa: F811
    from mamma_kit.landmarks.model import build_model
    from mamma_kit.landmarks.weights import save_weights

    torch.manual_seed(0)
    save_weights(tmp_path / "m.pt", build_model("tiny"), "toy")
    r = cli("landmarks", ws, "--weights", tmp_path / "m.pt", "--json", "-q")
    assert r.code == 0, r.err
    whole = LandmarkTracks.load(ws / "landmarks" / "cam0.npz")
    r = cli("landmarks", ws, "--weights", tmp_path / "m.pt", "--unit-frames", "2", "--force", "--json", "-q")
    assert r.code == 0, r.err
    assert json.loads(r.out)["cameras"][0]["units"] == len(frame_ranges(T, 2)) > 1
    split = LandmarkTracks.load(ws / "landmarks" / "cam0.npz")
    assert np.array_equal(split.valid, whole.valid) and whole.valid.sum() > 0
    for key in ("xy", "sigma", "visibility", "contact", "floor_contact"):
        a, b = getattr(whole, key)[whole.valid], getattr(split, key)[split.valid]
        assert np.allclose(a, b, atol=1e-4), key  # crops are independent; batches differ only
    # the camera's manifest is written once its ranges are joined: a rerun skips it
    r = cli("landmarks", ws, "--weights", tmp_path / "m.pt", "--unit-frames", "2", "--json", "-q")
    assert r.code == 0 and json.loads(r.out)["cameras"][0]["skipped"]


def test_keypoints_split_into_frame_ranges_write_one_file_per_camera(ws, cli):  # noqa: F811
    r = cli("keypoints", ws, "--no-pictures", "--json", "-q")
    assert r.code == 0, r.err
    one = json.loads(r.out)["cameras"][0]
    whole = KeypointTracks.load(ws / "keypoints" / "cam0.npz")
    r = cli("keypoints", ws, "--no-pictures", "--unit-frames", "3", "--force", "--json", "-q")
    assert r.code == 0, r.err
    cam = json.loads(r.out)["cameras"][0]
    assert cam["units"] == len(frame_ranges(T, 3)) > 1 and cam["instances"] == one["instances"] > 0
    split = KeypointTracks.load(ws / "keypoints" / "cam0.npz")
    assert split.xy.shape == whole.xy.shape and np.array_equal(split.track_ids, whole.track_ids)
    assert np.array_equal(split.frame_times, whole.frame_times)
    # every range starts from the detector; within a range the ROIs follow as in one unit
    assert cam["detector_calls"] + cam["followed"] == one["detector_calls"] + one["followed"]
    assert cam["detector_calls"] >= one["detector_calls"]


def test_crop_shards_are_units_with_their_own_random_streams(tmp_path):
    """Each crop shard is a unit of work seeded by its index: the same shards whether one process
    or a pool renders them, and a shard does not depend on how many crops come after it."""
    from mamma_kit.synth.crops import write_crop_shards

    a = write_crop_shards("tiny", tmp_path / "a", 4, seed=3, shard_size=2, workers=1)
    b = write_crop_shards("tiny", tmp_path / "b", 3, seed=3, shard_size=2, workers=2)  # a pool of 2
    assert a["shards"] == b["shards"] == ["shard_0000.npz", "shard_0001.npz"]
    assert (a["count"], b["count"]) == (4, 3)
    a0, b0 = np.load(tmp_path / "a" / "shard_0000.npz"), np.load(tmp_path / "b" / "shard_0000.npz")
    assert set(a0.files) == set(b0.files) and all(np.array_equal(a0[k], b0[k]) for k in a0.files)
    a1, b1 = np.load(tmp_path / "a" / "shard_0001.npz"), np.load(tmp_path / "b" / "shard_0001.npz")
    assert len(b1["images"]) == 1 and all(np.array_equal(a1[k][:1], b1[k]) for k in a1.files)
    assert not np.array_equal(a0["images"][:1], a1["images"][:1])
