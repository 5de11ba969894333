"""LTC as AC-coupled or high-passed inputs record it: each transition a short spike (clipped
here) decaying back to the mid level. Encoded square LTC through a first-order high-pass with
a time constant of a fraction of a bit period, clipped at 40 % of its peak, with a little
noise, at 22.05/44.1/48 kHz and 25/29.97/30 fps: every frame decoded, each frame's start
within one sample of the encoder's truth (as the square form's is)."""

import numpy as np
import pytest
from scipy.signal import lfilter

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.timecode import parse_timecode, timecode_to_frames
from mamma_kit.synth.audio import LtcSpec, Microphone, render_camera_audio, render_ltc
from mamma_kit.timing.ltc import decode_ltc, find_ltc_channel, looks_like_ltc, ltc_clock, word_rate

DURATION = 3.0
T0 = 0.0123  # first word's start (s): transitions fall at every sub-sample phase


def high_passed_ltc(sr, fps, tau_bits, clip=0.4, noise=0.003, seed=0, duration=DURATION):
    """(square (N,), high-passed (N,), spec, words per second): the encoder's square at sample
    times n / sr through a one-pole RC high-pass y[n] = a (y[n-1] + x[n] - x[n-1]) with time
    constant ``tau_bits`` bit periods, clipped at ``clip`` of its peak, scaled, plus noise."""
    df = fps == 29.97
    spec = LtcSpec(fps=fps, start_tc="01:00:59;20" if df else "01:00:59:20", drop_frame=df, user_bits=0x20260121,
                   t_ref_start=T0, level=0.5)
    t = np.arange(int(duration * sr)) / sr
    sq = render_ltc(t, 1.0 / sr, spec).astype(np.float64)
    rate = float(word_rate(fps))
    rc = tau_bits * sr / (80 * rate)  # samples
    a = rc / (rc + 1.0)
    y = lfilter([a, -a], [1.0, -a], sq)
    if clip:
        pk = float(np.abs(y).max())
        y = np.clip(y, -clip * pk, clip * pk)
    y = 0.8 * y / np.abs(y).max() + np.random.default_rng(seed).normal(0, noise, len(y))
    return sq, y, spec, rate


def truth(spec, rate, sr, n):
    """Counts (F,) and start samples (F,) of every word that lies wholly inside the n samples."""
    n_start = timecode_to_frames(parse_timecode(spec.start_tc), spec.fps)
    k = np.arange(int(np.ceil((1.0 / sr - T0) * rate)), int(np.floor(((n - 2) / sr - T0) * rate)))
    return n_start + k, (T0 + k / rate) * sr


def start_errors(fr, spec, rate, sr, n):
    count, start = truth(spec, rate, sr, n)
    i = np.searchsorted(count, fr.count_f)
    ok = (i < len(count)) & (count[np.minimum(i, len(count) - 1)] == fr.count_f)
    assert ok.all(), "decoded a frame label that is not in the take"
    return count, fr.start_f - start[i]


@pytest.mark.parametrize("fps", [25, 29.97, 30])
@pytest.mark.parametrize("sr", [22050, 44100, 48000])
@pytest.mark.parametrize("tau_bits", [0.05, 0.15, 0.3])
def test_high_passed_clipped_ltc_every_frame_within_one_sample(sr, fps, tau_bits):
    sq, y, spec, rate = high_passed_ltc(sr, fps, tau_bits, seed=int(sr * tau_bits))
    assert looks_like_ltc(y)
    fr = decode_ltc(y, sr)
    assert fr.form == "differentiated"
    count, err = start_errors(fr, spec, rate, sr, len(y))
    assert set(fr.count_f.tolist()) == set(count.tolist())  # every frame
    assert np.all(fr.user_bits_f == 0x20260121) and np.all(fr.drop_frame_f == (fps == 29.97))
    assert not fr.reverse_f.any()
    assert np.abs(err).max() < 0.5, np.abs(err).max()  # samples
    # the square form of the same take: the same frames, the same times
    fs = decode_ltc(sq + np.random.default_rng(1).normal(0, 0.003, len(sq)), sr)
    assert fs.form == "square" and np.array_equal(fs.count_f, fr.count_f)
    assert np.abs(fs.start_f - fr.start_f).max() < 0.5
    # the clock fit: the rate from the frames, every frame counted
    lc = ltc_clock(fr, 0.0, len(y) / sr)
    assert lc.fraction == 1.0 and lc.fps_name == {25: "25", 29.97: "29.97", 30: "30"}[fps]
    n_start = timecode_to_frames(parse_timecode(spec.start_tc), fps)
    assert abs(lc.clock.offset - (n_start / float(word_rate(fps)) - T0)) * sr < 0.5
    assert abs(lc.clock.rate_ppm) < 1.0


@pytest.mark.parametrize("sr,fps", [(22050, 30), (48000, 25)])
def test_high_passed_ltc_unclipped_noisier_and_reversed(sr, fps):
    # no clipping, and ten times the noise: still every frame, within a sample
    _, y, spec, rate = high_passed_ltc(sr, fps, 0.2, clip=None, noise=0.01, seed=3)
    fr = decode_ltc(y, sr)
    count, err = start_errors(fr, spec, rate, sr, len(y))
    assert fr.form == "differentiated" and set(fr.count_f.tolist()) == set(count.tolist())
    assert np.abs(err).max() < 1.0
    # a recording played backwards: the frames read in reverse
    _, y, spec, rate = high_passed_ltc(sr, fps, 0.1, seed=4)
    fr = decode_ltc(y[::-1].copy(), sr)
    assert fr.n >= len(truth(spec, rate, sr, len(y))[0]) - 1 and fr.reverse_f.all()


def test_find_ltc_channel_takes_the_high_passed_channel_and_not_the_microphone():
    sr = 48000
    _, y, spec, rate = high_passed_ltc(sr, 25, 0.1, seed=5)
    mic = Microphone((0, 0, 0), ClockModel(0.0, 0.0), DURATION, 0.0)
    x = render_camera_audio({"a": mic}, [], sample_rate=sr, snr_db=10, n_channels=1)["a"][0][:, 0]
    assert not looks_like_ltc(x)
    n = min(len(x), len(y))
    found = find_ltc_channel(np.stack([x[:n], y[:n]], 1), sr)
    assert found is not None and found[0] == 1 and found[1].form == "differentiated"
    # a signal of neither form is no LTC: white noise, and noise through the same high-pass
    rng = np.random.default_rng(6)
    assert not looks_like_ltc(rng.normal(0, 0.1, sr * 2))
    assert not looks_like_ltc(lfilter([1, -1], [1, -0.5], rng.normal(0, 0.1, sr * 2)))
