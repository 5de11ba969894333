"""Timing building blocks on arrays: timecode arithmetic, LTC encode/decode, GCC-PHAT,
robust line fits, the frame timeline."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.timecode import frames_to_timecode, parse_timecode, timecode_to_frames
from mamma_kit.synth.audio import LtcSpec, Microphone, clap_waveform, ltc_frame_starts, render_camera_audio, render_ltc
from mamma_kit.timing.fit import relative_clock, robust_line
from mamma_kit.timing.gcc import gcc_phat
from mamma_kit.timing.ltc import decode_ltc, ltc_clock
from mamma_kit.timing.timeline import timeline

RATES = [23.976, 24, 25, 29.97, 30, 50, 59.94, 60]


@given(n=st.integers(0, 24 * 3600 * 30 - 1), rate=st.sampled_from([29.97, 59.94, 25, 30, 24]))
def test_timecode_round_trip(n, rate):
    df = rate in (29.97, 59.94)
    if df:
        n = n % (24 * 3600 * round(rate) - 24 * 6 * 9 * (2 * round(rate) // 30))  # frames in a DF day
    else:
        n = n % (24 * 3600 * round(rate))
    tc = frames_to_timecode(n, rate, df)
    assert timecode_to_frames(tc, rate) == n
    assert parse_timecode(str(tc)) == tc


def test_drop_frame_skips_labels():
    # 29.97 DF: 00:00:59;29 is followed by 00:01:00;02; every tenth minute keeps ;00
    n = timecode_to_frames("00:00:59;29", 29.97)
    assert str(frames_to_timecode(n + 1, 29.97, True)) == "00:01:00;02"
    n = timecode_to_frames("00:09:59;29", 29.97)
    assert str(frames_to_timecode(n + 1, 29.97, True)) == "00:10:00;00"
    # an hour of DF labels is 107892 frames at 29.97
    assert timecode_to_frames("01:00:00;00", 29.97) == 107892


@settings(max_examples=25, deadline=None)
@given(rate=st.sampled_from(RATES), sr=st.sampled_from([44100, 48000]), ub=st.integers(0, 2**32 - 1),
       h=st.integers(0, 23), m=st.integers(0, 59), s=st.integers(0, 59), reverse=st.booleans(),
       ppm=st.floats(-300, 300))
def test_ltc_encode_decode_round_trip(rate, sr, ub, h, m, s, reverse, ppm):
    df = rate in (29.97, 59.94)
    spec = LtcSpec(fps=rate, start_tc=f"{h:02d}:{m:02d}:{s:02d}{';' if df else ':'}04", drop_frame=df,
                   user_bits=ub, t_ref_start=0.01)
    mic = Microphone((0, 0, 0), ClockModel(0.0, ppm * 1e-6), 0.6, 0.0)
    x, start = render_camera_audio({"a": mic}, [], sample_rate=sr, ltc=spec, snr_db=30)["a"]
    y = x[::-1, 1] if reverse else x[:, 1]
    fr = decode_ltc(y, sr, fps_hint=rate)
    count, t_cam = ltc_frame_starts(mic, spec)
    assert fr.n >= len(count) - 1 and fr.n >= 5
    assert set(fr.count_f.tolist()) <= set(count.tolist()) | {count[0] - 1, count[-1] + 1}
    assert np.all(fr.user_bits_f == ub) and np.all(fr.reverse_f == reverse)
    assert np.all(fr.drop_frame_f == df)
    if not reverse:  # each frame tied to its sample
        i = np.searchsorted(count, fr.count_f)
        ok = (i < len(count)) & (count[np.minimum(i, len(count) - 1)] == fr.count_f)
        err = start + fr.start_f[ok] / sr - t_cam[i[ok]]
        assert np.abs(err).max() * sr < 0.2


def test_ltc_survives_dropout_and_noise():
    sr = 48000
    spec = LtcSpec(fps=25, start_tc="10:00:00:00")
    mic = Microphone((0, 0, 0), ClockModel(0.2, -50e-6), 8.0, 0.0)
    x = render_camera_audio({"a": mic}, [], sample_rate=sr, ltc=spec)["a"][0][:, 1].copy()
    x[100000:124000] = 0  # half a second of dropout
    x[200000:201000] += np.random.default_rng(0).normal(0, 0.5, 1000)  # a burst of noise
    fr = decode_ltc(x, sr)
    lc = ltc_clock(fr, 0.0, 8.0)
    assert lc.expected in (198, 199) and lc.decoded >= lc.expected - 16  # 0.5 s lost = 12.5 frames
    true_off = 0.2 + 36000.0  # 10:00:00:00 starts at reference 0
    assert abs(lc.clock.offset - true_off) * sr < 0.1 and abs(lc.clock.rate_ppm + 50) < 0.1


@settings(max_examples=20, deadline=None)
@given(delay=st.floats(-40, 40), seed=st.integers(0, 1000))
def test_gcc_phat_subsample_delay(delay, seed):
    sr = 48000
    rng = np.random.default_rng(seed)
    w = clap_waveform(sr, rng)
    n = 512
    a = np.zeros(n)
    b = np.zeros(n)
    a[100:100 + len(w)] = w
    # b = a delayed by `delay` samples, exactly band-limited (Fourier shift)
    f = np.fft.rfftfreq(2048)
    pad = np.zeros(2048)
    pad[:n] = a
    b = np.fft.irfft(np.fft.rfft(pad) * np.exp(-2j * np.pi * f * delay), 2048)[:n]
    noise = 0.02
    a += rng.normal(0, noise, n)
    b += rng.normal(0, noise, n)
    g = gcc_phat(a, b, sr, max_lag=60, band=(500, 8000))
    assert abs(g.lag - delay) < 0.25 and g.psr > 5  # 0.25 sample = 5 us, a tenth of the 0.05 ms goal


def test_robust_line_ignores_outliers():
    rng = np.random.default_rng(0)
    x = np.linspace(0, 300, 40)
    y = 1.0001 * x + 0.25 + rng.normal(0, 1e-6, 40)
    y[[5, 17]] += [0.01, -0.3]
    lf = robust_line(x, y)
    assert abs(lf.slope - 1.0001) < 1e-8 and abs(lf.intercept - 0.25) < 1e-5
    assert not lf.inlier_n[5] and not lf.inlier_n[17] and lf.inlier_n.sum() == 38


def test_relative_clock_composes():
    cam, ref = ClockModel(1.5, 80e-6), ClockModel(-0.5, -20e-6)
    off, rate = relative_clock(cam, ref)
    t = np.array([0.0, 100.0, 300.0])
    assert np.allclose(ClockModel(off, rate).to_ref(t), ref.to_cam(cam.to_ref(t)), atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), off=st.floats(-2, 2), ppm=st.floats(-300, 300))
def test_timeline_picks_nearest_vfr_frame(seed, off, ppm):
    rng = np.random.default_rng(seed)
    ts = np.cumsum(rng.uniform(1 / 40, 1 / 20, 200))
    clk = {"ref": ClockModel(), "b": ClockModel(off, ppm * 1e-6)}
    t_ref = rng.uniform(-3, 12, 300)
    tl = timeline(clk, {"ref": ts, "b": ts}, t_ref)
    idx, res = tl["b"]
    tr = clk["b"].to_ref(ts)
    brute = np.argmin(np.abs(t_ref[:, None] - tr[None, :]), axis=1)
    inside = idx >= 0
    assert np.array_equal(idx[inside], brute[inside])
    assert np.allclose(res[inside], t_ref[inside] - tr[idx[inside]])
    assert np.all((t_ref[~inside] < tr[0]) | (t_ref[~inside] > tr[-1]))
    assert np.all(np.isnan(res[~inside]))
