"""Flash sync: a light switched on (or a torch flashed) timed within the frame from partly exposed
frames and rolling-shutter rows; several flashes matched across cameras with drift; the error when a
camera saw no flash; auto choosing among the methods and reporting how they agree."""

from __future__ import annotations

import numpy as np
import pytest

from mamma_kit.core.clock import ClockModel
from mamma_kit.synth.render import flash_rows
from mamma_kit.timing.flash import GRID_COLS, GRID_ROWS, FlashSignal, camera_events, flash_clocks


def frame_times(fps: float, seconds: float, rng, jitter_s: float = 0.0006) -> np.ndarray:
    t = np.arange(0, seconds, 1 / fps)
    return np.sort(t + rng.normal(0, jitter_s, len(t)))  # variable frame rate


def grid_signal(clock: ClockModel, t_cam: np.ndarray, on_s, off_s, exposure: float, readout: float, seed=0,
                noise=0.002, gain=0.8) -> FlashSignal:
    """A camera's brightness grid (linear) under a flash, each row integrating over its exposure:
    the renderer's own flash model (synth.render.flash_rows), the image gamma undone."""
    rng = np.random.default_rng(seed)
    base_rc = rng.uniform(0.05, 0.4, (GRID_ROWS, GRID_COLS))
    rows = np.stack([flash_rows(clock, float(t), GRID_ROWS, exposure, readout, np.asarray(on_s, float),
                                np.asarray(off_s, float), gain) for t in t_cam]) ** 2.2  # (T, rows) linear
    lum = base_rc[None] * rows[:, :, None] + rng.normal(0, noise, (len(t_cam), GRID_ROWS, GRID_COLS))
    return FlashSignal(t_cam, lum.astype(np.float32), np.zeros(lum.shape, bool))


@pytest.mark.parametrize("fps,exposure,readout,known", [
    (30.0, 0.032, 0.0, True),      # global shutter, exposure given: the partly lit frame's fraction
    (30.0, 0.012, 0.026, True),    # phone rolling shutter: the rows where the light comes on
    (60.0, 0.010, 0.012, True),
    (30.0, 0.019, 0.0, False),     # exposure unknown: assumed half a frame (the issue asks 4 ms)
    (30.0, 0.010, 0.0, True),      # short global exposures leave gaps no frame sees
])
def test_flash_is_timed_within_the_frame(fps, exposure, readout, known):
    rng = np.random.default_rng(int(fps + 1e3 * exposure))
    clock = ClockModel(0.0, 0.0)
    t_cam = frame_times(fps, 3.0, rng)
    period = 1 / fps
    errs = []
    for t_on in 1.0 + rng.uniform(0, period, 4):  # onsets anywhere within a frame
        sig = grid_signal(clock, t_cam, [t_on], [t_on + 0.8], exposure, readout, seed=int(t_on * 1e4))
        evs, _ = camera_events(sig, {"exposure_s": exposure if known else 0.0})
        assert [e.sign for e in evs] == [1, -1]
        for ev, t_true in zip(evs, (t_on, t_on + 0.8)):
            errs.append(ev.t - t_true)
            if ev.observations == 0:  # in a gap between exposures: its middle, and it says how unsure
                assert abs(errs[-1]) < 0.5 * (period - exposure) + 1e-3 and ev.precision_s > 0.2 * (period - exposure)
                errs[-1] = 0.0
    # whole-frame methods err up to half a frame (16.7 ms at 30 fps); the issue asks 4 ms
    assert np.abs(errs).max() < (0.5e-3 if known else 4e-3), np.array(errs) * 1e3
    if exposure + readout < 0.5 * period:
        assert 0.0 in errs  # the gap case was met


def test_several_flashes_matched_across_cameras_give_offset_and_drift():
    rng = np.random.default_rng(3)
    truth = {"cam0": ClockModel(0.0, 0.0), "cam1": ClockModel(0.4137, 40e-6), "cam2": ClockModel(-0.2561, -30e-6)}
    flashes = np.array([2.0, 31.0, 58.0])  # reference (scene) times a torch went on, for 0.5 s each
    sigs = {}
    for i, (n, c) in enumerate(truth.items()):
        t_cam = frame_times(30.0, 62.0, rng)
        sigs[n] = grid_signal(c, t_cam, flashes, flashes + 0.5, 0.015, 0.02, seed=i)
    sigs["cam2"].lum_trc[900:] *= 1.0005  # a slow change in the scene is no flash
    clocks, diag, warnings = flash_clocks(sigs, "cam0", {"exposure_s": 0.015})
    for n, c in truth.items():
        assert len(diag[n]["flashes"]) == 6  # three on, three off
        assert clocks[n].offset == pytest.approx(c.offset, abs=0.5e-3), n
        assert clocks[n].rate == pytest.approx(c.rate, abs=3e-6), n
    assert not warnings


def write_flash_videos(tmp_path, clocks: dict[str, ClockModel], flashes, fps=30.0, seconds=2.4, size=(96, 64),
                       exposure=0.02, readout=0.02, timecode=False, dark: set[str] = frozenset()):
    """H.264 videos of a textured scene a torch lights (rows integrating over the exposure)."""
    from mamma_kit.core.timecode import frames_to_timecode
    from mamma_kit.video import VideoWriter

    rng = np.random.default_rng(1)
    w, h = size
    base = (rng.uniform(30, 140, (h // 4, w // 4, 3)).repeat(4, 0).repeat(4, 1) / 255.0)
    on = np.asarray(flashes, float)
    paths, stamps = {}, {}
    for i, (n, clk) in enumerate(clocks.items()):
        t = np.round(frame_times(fps, seconds, np.random.default_rng(10 + i)) * 90000) / 90000
        t = t - t[0]
        tc = str(frames_to_timecode(int(round((3600.0 + float(clk.to_ref(t[0]))) * fps)), fps)) if timecode else None
        p = tmp_path / f"{n}.mp4"
        with VideoWriter(p, w, h, fps=fps, crf=12, timecode=tc) as wr:
            for tk in t:
                light = np.ones(h) if n in dark else flash_rows(clk, float(tk), h, exposure, readout, on, on + 0.8, 0.8)
                img = base * light[:, None, None] + rng.normal(0, 0.5 / 255, base.shape)
                wr.write_frame(np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8), float(tk))
        paths[n], stamps[n] = p, t
    return paths, stamps


CLOCKS = {"cam0": ClockModel(0.0, 0.0), "cam1": ClockModel(0.1371, 0.0), "cam2": ClockModel(-0.2113, 0.0)}


def test_flash_sync_of_videos_through_the_cli(tmp_path, cli):
    from mamma_kit.core.timingfile import read_timing

    paths, _ = write_flash_videos(tmp_path, CLOCKS, [1.0])
    res = cli("sync", *paths.values(), "--method", "flash", "--exposure-ms", 20, "--no-plots", "--out",
              tmp_path / "t.toml")
    assert res.code == 0, res.err
    clocks, meta = read_timing(tmp_path / "t.toml")
    assert meta["method"] == "flash"
    for n, c in CLOCKS.items():
        assert clocks[n].offset == pytest.approx(c.offset, abs=1e-3), n  # the issue asks 4 ms
        assert clocks[n].confidence > 0.5


def test_no_flash_found_is_one_line_and_keeps_what_was_computed(tmp_path, cli):
    from mamma_kit.pipeline import init_workspace

    paths, _ = write_flash_videos(tmp_path, CLOCKS, [1.0], dark={"cam2"})
    init_workspace(tmp_path / "ws", list(paths.values()))
    ws = tmp_path / "ws"
    (ws / "timing.toml").write_text("# kept\n")
    res = cli("sync", ws, "--method", "flash", "--no-plots")
    assert res.code == 2, res
    line = res.err.strip().splitlines()[-1]
    assert line.startswith("mamma-kit: error: no flash found in cam2.mp4") and "Traceback" not in res.err
    assert "seen by cam0, cam1" in line and "torch" in line and "--method" in line
    assert (ws / "timing.toml").read_text() == "# kept\n"  # the previous clocks stay
    # every camera's brightness signal is kept: a rerun does not decode the videos again
    assert sorted(p.stem for p in (ws / ".cache" / "flash").glob("*.npz")) == ["cam0", "cam1", "cam2"]


def test_auto_chooses_the_most_precise_method_and_reports_agreement(tmp_path, cli):
    """Flash videos with a tmcd start timecode and a log of every frame's time: auto uses the log,
    and reports flash and tmcd against it."""
    from mamma_kit.core.io import read_toml

    paths, stamps = write_flash_videos(tmp_path, CLOCKS, [1.0], timecode=True)
    rows = ["sync_index,cam_id,frame_time"] + [f"{k},{i},{float(CLOCKS[n].to_ref(t)) + 50.0:.9f}"
                                               for i, n in enumerate(CLOCKS) for k, t in enumerate(stamps[n])]
    (tmp_path / "timestamps.csv").write_text("\n".join(rows) + "\n")
    res = cli("sync", *paths.values(), "--method", "auto", "--timestamps", tmp_path / "timestamps.csv", "--no-plots",
              "--exposure-ms", 20, "--out", tmp_path / "t.toml")
    assert res.code == 0, res.err
    t = read_toml(tmp_path / "t.toml")
    assert t["method"] == "timestamps"
    d = t["diagnostics"]
    assert {"timestamps", "flash", "tmcd"} <= set(d["methods_ok"])
    assert d["agreement"]["flash-timestamps"]["max_abs_ms"] < 1.0
    assert d["agreement"]["flash-timestamps"]["cameras"] == 2
    assert d["agreement"]["tmcd-timestamps"]["max_abs_ms"] < 1e3 / 30  # tmcd: whole frames
    assert "audio" in d["not_used"] and "motion" in d["not_used"]
    assert abs(t["cameras"]["cam2"]["diagnostics"]["agreement_ms"]["flash-timestamps"]) < 1.0
    # without the log, auto takes the flash over the whole-frame timecode
    res = cli("sync", *paths.values(), "--no-plots", "--exposure-ms", 20, "--out", tmp_path / "t2.toml")
    assert res.code == 0, res.err
    t2 = read_toml(tmp_path / "t2.toml")
    assert t2["method"] == "flash" and "tmcd-flash" in t2["diagnostics"]["agreement"]
    for n, c in CLOCKS.items():
        assert t2["cameras"][n]["offset_s"] == pytest.approx(c.offset, abs=1e-3)
