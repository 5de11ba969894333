"""`mamma-kit sync` by claps on real files (H.264 + AAC, VFR frames, drifting clocks) against
the true clock models; tmcd; the timeline; failures with their one-line messages."""

import json

import numpy as np
import pytest

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.io import read_npz, read_toml
from mamma_kit.core.timingfile import read_timing
from mamma_kit.synth.audio import write_sync_workspace
from mamma_kit.video import VideoWriter

CLOCKS3 = [ClockModel(0.0, 0.0), ClockModel(0.4123, 85e-6), ClockModel(-1.2345, -120e-6)]


def _eval(cli, ws):
    r = cli("eval", ws, "--json", "--only", "timing")
    assert r.code == 0, r
    return json.loads(r.out)["timing"]


@pytest.fixture(scope="module")
def weak_ws(tmp_path_factory):
    ws = tmp_path_factory.mktemp("weak")
    # mixed sample rates: phones record 44.1 or 48 kHz; tmcd on every file
    info = write_sync_workspace(ws, n_cameras=3, duration_s=16, fps=10, clap_times=[3.0, 12.0], clocks=CLOCKS3,
                                sample_rate=[48000, 44100, 48000], reverb="weak", snr_db=10, timecode=True, seed=1)
    return ws, info


def test_clap_weak_reverb_within_0_05_ms(cli, weak_ws):
    ws, info = weak_ws
    r = cli("sync", ws, "--json")
    assert r.code == 0, r
    out = json.loads(r.out)
    assert out["method"] == "clap" and out["reference"] == "cam0"
    for name, cam in out["cameras"].items():
        assert set(cam) >= {"offset_s", "rate_ppm", "method", "confidence"}
        assert cam["method"] == "clap" and cam["confidence"] > 0.8
    ev = _eval(cli, ws)
    assert ev["worst_mapping_error_ms"] < 0.05, ev
    assert ev["worst_offset_error_ms"] < 0.05
    # the files the command promises
    clocks, meta = read_timing(ws / "timing.toml")
    assert meta["diagnostics"]["clap"]["sound_travel_corrected"] is True
    assert meta["diagnostics"]["clap"]["loop_closure_max_ms"] < 0.05
    d1 = meta["cameras"]["cam1"]
    assert d1["clap"]["events"] == 2 and len(d1["clap"]["residuals_ms"]) == 2
    # tmcd cross-check: whole frames at 10 fps agree within a frame, so no warning
    assert abs(d1["agreement_ms"]["tmcd-clap"]) < 100.0 + 1e-6
    assert not out["warnings"]
    for png in ("offsets.png", "residuals.png", "peaks.png", "agreement.png"):
        assert (ws / "report" / "sync" / png).stat().st_size > 5000
    # timeline: each camera's frame nearest to the reference camera's frames, by the true clocks
    tl = read_npz(ws / "timing_timeline.npz")
    assert list(tl["cameras"]) == ["cam0", "cam1", "cam2"]
    ts = info["frame_times"]
    truth = info["clocks"]
    t_scene = truth["cam0"].to_ref(ts["cam0"])
    for c, name in enumerate(tl["cameras"]):
        idx = tl["frame_index_ct"][c]
        tr = truth[name].to_ref(ts[name])
        ok = idx >= 0
        brute = np.argmin(np.abs(t_scene[ok, None] - tr[None, :]), axis=1)
        assert np.array_equal(idx[ok], brute)
        # residuals differ from the truth only by the sync error (< 0.05 ms)
        assert np.nanmax(np.abs(tl["residual_s_ct"][c][ok] - (t_scene[ok] - tr[brute]))) < 5e-5
        assert ok.mean() > 0.7


def test_tmcd_whole_frame_offsets(cli, weak_ws):
    ws, info = weak_ws
    r = cli("sync", ws, "--method", "tmcd", "--out", ws / "tmcd.toml", "--json", "--no-plots")
    assert r.code == 0, r
    out = json.loads(r.out)
    truth = info["clocks"]
    for n, cam in out["cameras"].items():
        o_t = (truth[n].offset - truth["cam0"].offset) / (1 + truth["cam0"].rate)
        assert cam["method"] == "tmcd" and cam["rate_ppm"] == 0.0
        assert abs(cam["offset_s"] - o_t) <= 1 / 10 + 1e-6  # one frame at 10 fps
        assert n == "cam0" or cam["confidence"] < 0.5  # the reference is exact by definition


def test_clap_strong_reverb_within_0_5_ms(cli, tmp_path):
    write_sync_workspace(tmp_path, n_cameras=3, duration_s=12, fps=5, clap_times=[2.5, 9.0], clocks=CLOCKS3,
                         reverb="strong", snr_db=10, seed=2)
    r = cli("sync", tmp_path, "--preset", "clap", "--json", "--no-plots")
    assert r.code == 0, r
    ev = _eval(cli, tmp_path)
    # measured about 0.005 ms; the brief's bar for room reverberation is 0.5 ms
    assert ev["worst_mapping_error_ms"] < 0.5, ev


def test_drift_over_five_minutes(cli, tmp_path):
    truth = [ClockModel(0.0, 0.0), ClockModel(0.8, 140e-6)]
    write_sync_workspace(tmp_path, n_cameras=2, duration_s=300, fps=1, clap_times=[10.0, 290.0], clocks=truth,
                         reverb="weak", snr_db=10, seed=3)
    r = cli("sync", tmp_path, "--method", "clap", "--json", "--no-plots")
    assert r.code == 0, r
    ev = _eval(cli, tmp_path)
    assert ev["worst_drift_error_ppm"] < 2.0, ev
    assert ev["worst_mapping_error_ms"] < 0.05, ev
    assert abs(json.loads(r.out)["cameras"]["cam1"]["rate_ppm"] - 140.0) < 2.0


def test_videos_mode_without_travel_correction(cli, tmp_path):
    info = write_sync_workspace(tmp_path, n_cameras=2, duration_s=10, fps=5, clap_times=[4.0], reverb="none",
                                clocks=CLOCKS3[:2], seed=4)
    v = info["videos"]
    r = cli("sync", v["cam0"], v["cam1"], "--out", tmp_path / "t.toml", "--json")
    assert r.code == 0, r
    out = json.loads(r.out)
    mic, clap = info["mics"], info["claps"][0]
    travel = (np.linalg.norm(np.subtract(clap.position, mic["cam1"].position))
              - np.linalg.norm(np.subtract(clap.position, mic["cam0"].position))) / 343.0
    # one clap: offset only (drift held at 0), off by exactly the uncorrected travel difference
    cam1 = out["cameras"]["cam1"]
    assert cam1["rate_ppm"] == 0.0
    t_mid = 5.0
    true_map = CLOCKS3[1].to_ref(t_mid) - CLOCKS3[0].offset
    est_map = (1 + cam1["rate_ppm"] * 1e-6) * t_mid + cam1["offset_s"]
    assert abs(est_map - true_map + travel) < 0.05e-3 + abs(CLOCKS3[1].rate) * t_mid
    assert (tmp_path / "t_plots" / "offsets.png").is_file()
    assert read_toml(tmp_path / "t.toml")["producer"]["inputs"]["cam1"]


# ---- failures: one line, exit code 2 -----------------------------------------------------
def _silent_or_mute(path, audio: bool, n=20):
    kw = dict(audio_rate=48000, audio_codec="aac") if audio else {}
    with VideoWriter(path, 32, 24, fps=10, **kw) as w:
        for i in range(n):
            w.write_frame(np.zeros((24, 32, 3), np.uint8), i / 10)
        if audio:
            w.write_audio(np.zeros((48000 * n // 10, 1), np.float32), start_s=0.0)
    return path


def _one_line_error(r, *needles):
    assert r.code == 2, r
    line = r.err.strip().splitlines()[-1]
    assert line.startswith("mamma-kit: error:")
    for s in needles:
        assert s in line, line
    assert "Traceback" not in r.err


def test_no_audio_stream(cli, tmp_path):
    a = _silent_or_mute(tmp_path / "a.mp4", audio=False)
    b = _silent_or_mute(tmp_path / "b.mp4", audio=False)
    _one_line_error(cli("sync", a, b, "--method", "clap"), "a.mp4 has no audio stream", "record with sound on")
    # auto without audio and without timecode says what was tried
    _one_line_error(cli("sync", a, b), "no sync method worked")


def test_silent_audio(cli, tmp_path):
    a = _silent_or_mute(tmp_path / "a.mp4", audio=True)
    b = _silent_or_mute(tmp_path / "b.mp4", audio=True)
    _one_line_error(cli("sync", a, b, "--method", "clap"), "audio of a.mp4 is silent", "microphone")


def test_no_clap_found_says_where_it_looked(cli, tmp_path):
    info = write_sync_workspace(tmp_path, n_cameras=2, duration_s=3, fps=5, clap_times=[], seed=5)
    v = info["videos"]
    _one_line_error(cli("sync", v["cam0"], v["cam1"], "--method", "clap"), "no clap found in cam0.mp4",
                    "looked for sharp onsets", "channel 0", "camera time")


def test_no_ltc_found(cli, tmp_path):
    info = write_sync_workspace(tmp_path, n_cameras=2, duration_s=4, fps=5, clap_times=[1.5], seed=6)
    v = info["videos"]
    _one_line_error(cli("sync", v["cam0"], v["cam1"], "--preset", "ltc-25"), "no LTC found in cam0.mp4",
                    "timecode generator")


def test_unknown_preset_and_reference(cli, weak_ws):
    ws, _ = weak_ws
    _one_line_error(cli("sync", ws, "--preset", "nope"), "unknown sync preset 'nope'", "ltc-25")
    _one_line_error(cli("sync", ws, "--reference", "camX"), "reference camera 'camX'")


@pytest.mark.parametrize("sr", [48000, 44100])
def test_late_audio_start_keeps_sample_time(tmp_path, sr):
    # audio starting after the AAC priming (an edit list in the file) stays on its sample
    from mamma_kit.video import read_audio

    x = np.zeros((sr * 2, 1), np.float32)
    x[sr + 321, 0] = 0.9
    p = tmp_path / "late.mp4"
    with VideoWriter(p, 32, 24, fps=5, audio_rate=sr) as w:
        for i in range(8):
            w.write_frame(np.zeros((24, 32, 3), np.uint8), 0.1 + i / 5)
        w.write_audio(x, start_s=0.03)
    a = read_audio(p)
    assert abs(a.start_s * sr + np.argmax(np.abs(a.mono())) - (round(0.03 * sr) + sr + 321)) <= 1


def test_tmcd_that_disagrees_with_claps_warns(cli, tmp_path):
    write_sync_workspace(tmp_path, n_cameras=2, duration_s=5, fps=10, clap_times=[2.0], clocks=CLOCKS3[:2],
                         timecode=True, timecode_shift_s={"cam1": 0.5}, seed=11)
    r = cli("sync", tmp_path, "--json", "--no-plots")
    assert r.code == 0, r
    out = json.loads(r.out)
    assert out["method"] == "clap"
    assert any("cam1: tmcd and clap disagree by" in w for w in out["warnings"]), out["warnings"]
    assert "warning:" in r.err
