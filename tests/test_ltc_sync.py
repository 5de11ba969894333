"""`mamma-kit sync` by LTC on real files: every frame decoded at 44.1/48 kHz and 25/29.97/30
fps, offsets within one sample of the true clocks; clap vs LTC disagreement is an error."""

import json

import pytest

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.timingfile import read_timing
from mamma_kit.synth.audio import LtcSpec, write_sync_workspace

CLOCKS = [ClockModel(0.0, 0.0), ClockModel(0.7311, 95e-6)]


@pytest.mark.parametrize("sr,fps,df", [(44100, 25, False), (48000, 25, False), (44100, 29.97, True),
                                       (48000, 29.97, False), (44100, 30, False), (48000, 30, False)])
def test_ltc_every_frame_within_one_sample(cli, tmp_path, sr, fps, df):
    ltc = LtcSpec(fps=fps, start_tc="01:00:00;00" if df else "01:00:00:00", drop_frame=df, user_bits=0x20260101,
                  t_ref_start=0.0)
    write_sync_workspace(tmp_path, n_cameras=2, duration_s=6, fps=5, clap_times=[], clocks=CLOCKS, sample_rate=sr,
                         ltc=ltc, seed=int(sr + fps))
    preset = {25: "ltc-25", 30: "ltc-30"}.get(fps)
    args = ["--preset", preset] if preset else ["--method", "ltc"]
    r = cli("sync", tmp_path, *args, "--json", "--no-plots")
    assert r.code == 0, r
    out = json.loads(r.out)
    assert out["method"] == "ltc"
    _, meta = read_timing(tmp_path / "timing.toml")
    for n in ("cam0", "cam1"):
        d = meta["cameras"][n]["ltc"]
        assert d["decoded_fraction"] == 1.0 and d["decoded_frames"] >= 5 * 6 * fps / 5 - 2, d
        assert d["channel"] == 1 and d["user_bits"] == "20260101" and d["drop_frame"] == df
        assert d["fps"] == {25: "25", 29.97: "29.97", 30: "30"}[fps]
    assert out["cameras"]["cam1"]["confidence"] == 1.0
    r = cli("eval", tmp_path, "--json", "--only", "timing")
    ev = json.loads(r.out)["timing"]
    assert ev["worst_mapping_error_ms"] < 1e3 / sr, ev  # one sample
    assert ev["worst_drift_error_ppm"] < 2.0


def test_clap_and_ltc_that_disagree_stop_with_advice(cli, tmp_path):
    # cam1's timecode box was jammed 0.4 s off: the claps tell otherwise
    ltc = LtcSpec(fps=25, shift_s={"cam1": 0.4})
    write_sync_workspace(tmp_path, n_cameras=2, duration_s=6, fps=5, clap_times=[2.0], clocks=CLOCKS, ltc=ltc, seed=9)
    r = cli("sync", tmp_path, "--json", "--no-plots")
    assert r.code == 2, r
    line = r.err.strip().splitlines()[-1]
    assert "ltc and clap clocks disagree on cam1 by" in line or "clap and ltc clocks disagree on cam1 by" in line
    assert "--method ltc|clap" in line and "Traceback" not in r.err
    # each method alone still works
    assert cli("sync", tmp_path, "--method", "clap", "--no-plots").code == 0
    r = cli("sync", tmp_path, "--method", "ltc", "--json", "--no-plots")
    assert r.code == 0 and abs(json.loads(r.out)["cameras"]["cam1"]["offset_s"] - (0.7311 - 0.4)) < 1e-4


def test_auto_prefers_ltc_and_cross_checks_claps(cli, tmp_path):
    write_sync_workspace(tmp_path, n_cameras=2, duration_s=6, fps=5, clap_times=[2.0], clocks=CLOCKS,
                         ltc=LtcSpec(fps=30), seed=10)
    r = cli("sync", tmp_path, "--json", "--no-plots")
    assert r.code == 0, r
    out = json.loads(r.out)
    assert out["method"] == "ltc" and out["diagnostics"]["methods_ok"] == ["clap", "ltc"]
    _, meta = read_timing(tmp_path / "timing.toml")
    # the claps (sound travel corrected from the known positions) agree with the timecode
    assert abs(meta["cameras"]["cam1"]["agreement_ms"]["clap-ltc"]) < 0.05
