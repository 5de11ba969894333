"""Clocks the rig already knows: --method synced, --timestamps FILE, a timing.toml given by the user,
and `init --synced` (videos without audio)."""

from __future__ import annotations

import numpy as np
import pytest

from mamma_kit.core.io import read_toml
from mamma_kit.core.timingfile import read_timing


def silent_videos(tmp_path, n=3, frames=8, fps=30.0, starts=None):
    from mamma_kit.video.writer import write_video

    out = []
    for i in range(n):
        t0 = 0.0 if starts is None else starts[i]
        img = [np.full((48, 64, 3), 40 * i + 5 * k, np.uint8) for k in range(frames)]
        out.append(write_video(tmp_path / f"cam{i}.mp4", img, t0 + np.arange(frames) / fps))
    return out


def test_synced_gives_identical_clocks(tmp_path, cli):
    from mamma_kit.pipeline import init_workspace

    init_workspace(tmp_path / "ws", silent_videos(tmp_path))
    res = cli("sync", str(tmp_path / "ws"), "--method", "synced", "--json", "--no-plots")
    assert res.code == 0, res.err
    clocks, meta = read_timing(tmp_path / "ws" / "timing.toml")
    assert meta["method"] == "synced"
    assert all(c.offset == 0.0 and c.rate == 0.0 and c.source == "synced" for c in clocks.values())


def test_synced_warns_when_the_videos_start_far_apart(tmp_path, cli):
    vids = silent_videos(tmp_path, n=2, starts=[0.0, 0.5])
    res = cli("sync", *map(str, vids), "--method", "synced", "--no-plots")
    assert res.code == 0 and "first frames are 500.0 ms apart" in res.err


def test_timestamps_file_gives_each_cameras_offset_and_drift(tmp_path, cli):
    from mamma_kit.video import VideoReader

    vids = silent_videos(tmp_path, frames=12)
    true = {"0": (0.0, 0.0), "1": (0.0123, 40e-6), "2": (-0.031, -25e-6)}  # rig clock = (1 + r) t + o
    rows = ["sync_index,cam_id,frame_time"]
    for v, (cid, (o, r)) in zip(vids, true.items()):
        ts = VideoReader(v).timestamps
        rows += [f"{k},{cid},{(1 + r) * t + o + 100.0:.9f}" for k, t in enumerate(ts)]
    (tmp_path / "timestamps.csv").write_text("\n".join(rows) + "\n")
    res = cli("sync", *map(str, vids), "--timestamps", str(tmp_path / "timestamps.csv"), "--no-plots",
              "--out", str(tmp_path / "t.toml"))
    assert res.code == 0, res.err
    clocks, meta = read_timing(tmp_path / "t.toml")
    assert meta["method"] == "timestamps"
    for name, (cid, (o, r)) in zip(["cam0", "cam1", "cam2"], true.items()):
        # t_ref(t) = ((1 + r) t + o - o_ref) / (1 + r_ref), the reference (cam0) has o = r = 0
        assert clocks[name].offset == pytest.approx(o, abs=1e-7)
        assert clocks[name].rate == pytest.approx(r, abs=1e-7)


def test_timestamps_file_that_does_not_match_the_videos_is_one_line(tmp_path, cli):
    vids = silent_videos(tmp_path, n=2)
    (tmp_path / "ts.csv").write_text("sync_index,cam_id,frame_time\n0,0,0.0\n0,1,0.0\n")
    res = cli("sync", *map(str, vids), "--timestamps", str(tmp_path / "ts.csv"), "--no-plots")
    assert res.code == 2 and "lists 1 frames for camera cam0 but its video has 8" in res.err
    res = cli("sync", *map(str, vids), "--method", "timestamps", "--no-plots")
    assert res.code == 2 and "--timestamps FILE" in res.err


def test_a_given_timing_toml_is_kept_and_init_synced_runs_without_audio(tmp_path):
    from mamma_kit.core.clock import ClockModel
    from mamma_kit.core.timingfile import write_timing
    from mamma_kit.pipeline import capture_to_smplx, init_workspace

    vids = silent_videos(tmp_path)
    init_workspace(tmp_path / "ws", vids)
    given = {f"cam{i}": ClockModel(0.001 * i, 0.0, "lab", 1.0) for i in range(3)}
    write_timing(tmp_path / "ws" / "timing.toml", given, "cam0", "lab")
    before = (tmp_path / "ws" / "timing.toml").read_bytes()
    from conftest import make_ring_rig

    from mamma_kit.core.calibfile import write_calibration

    rig = make_ring_rig(3, size=(64, 48), f=60.0)
    for c, n in zip(rig, ["cam0", "cam1", "cam2"]):
        c.name = n
    write_calibration(tmp_path / "ws" / "calibration.toml", rig)
    run = capture_to_smplx(tmp_path / "ws", to_stage="sync", progress=False)
    assert run["stages"]["sync"]["status"] == "provided"
    assert (tmp_path / "ws" / "timing.toml").read_bytes() == before

    init_workspace(tmp_path / "ws2", vids, synced=True, calibration=tmp_path / "ws" / "calibration.toml")
    assert read_toml(tmp_path / "ws2" / "capture.toml")["settings"]["sync"]["method"] == "synced"
    run = capture_to_smplx(tmp_path / "ws2", to_stage="sync", progress=False)
    assert run["stages"]["sync"]["status"] == "ran"
    clocks, meta = read_timing(tmp_path / "ws2" / "timing.toml")
    assert meta["method"] == "synced" and all(c.offset == 0 for c in clocks.values())


def test_capture_to_smplx_with_motion_sync_and_no_people_is_one_line(tmp_path, cli):
    """Motion sync runs after track + keypoints in capture-to-smplx; videos with nobody in them end in
    one line that says so, exit 2."""
    from conftest import make_ring_rig

    from mamma_kit.core.calibfile import write_calibration
    from mamma_kit.pipeline import init_workspace
    from mamma_kit.video.writer import write_video

    rig = make_ring_rig(2, size=(160, 120), f=150.0)
    rng = np.random.default_rng(0)
    base = rng.uniform(40, 200, (30, 40, 3)).repeat(4, 0).repeat(4, 1)
    vids = [write_video(tmp_path / f"{c.name}.mp4", [np.clip(base + rng.normal(0, 2, base.shape), 0, 255)
                                                     .astype(np.uint8) for _ in range(4)], np.arange(4) / 10)
            for c in rig]
    write_calibration(tmp_path / "calib.toml", rig)
    init_workspace(tmp_path / "ws", vids, calibration=tmp_path / "calib.toml")
    text = (tmp_path / "ws" / "capture.toml").read_text().replace('[settings.track]', '[settings.track]\npictures = false')
    (tmp_path / "ws" / "capture.toml").write_text(text + '\n[settings.keypoints]\npictures = false\n'
                                                  '\n[settings.sync]\nmethod = "motion"\n')
    res = cli("capture-to-smplx", tmp_path / "ws")
    assert res.code == 2, res
    line = res.err.strip().splitlines()[-1]
    assert "no people tracked in cam0, cam1" in line and "Traceback" not in res.err
    assert (tmp_path / "ws" / "keypoints" / "cam0.npz").is_file()  # track and keypoints ran first
    assert not (tmp_path / "ws" / "timing.toml").exists()
