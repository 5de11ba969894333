"""Video I/O: exact VFR timestamps, audio on the video origin, timecode, corrupt files."""

import numpy as np
import pytest

from mamma_kit.core.errors import UserError
from mamma_kit.video import VideoReader, VideoWriter, read_audio, read_timecode, write_video

SR = 48000


def _irregular_times(n=40, seed=0):
    rng = np.random.default_rng(seed)
    dt = rng.uniform(1 / 40, 1 / 20, n - 1)
    return np.round(np.cumsum(np.r_[0.1, dt]) * 90000) / 90000  # representable on the 90 kHz clock


def _frames(n, h=48, w=64):
    return [np.full((h, w, 3), (7 * i) % 256, np.uint8) for i in range(n)]


def test_irregular_timestamps_read_back_exactly(tmp_path):
    ts = _irregular_times()
    p = write_video(tmp_path / "vfr.mp4", _frames(len(ts)), ts)
    r = VideoReader(p)
    assert r.n_frames == len(ts)
    assert np.array_equal(r.timestamps, ts) or np.abs(r.timestamps - ts).max() < 1e-12
    # decoded frames carry the same timestamps, in order, and the right content
    got = [(t, img[0, 0, 0]) for t, img in r.frames()]
    assert np.abs(np.array([g[0] for g in got]) - ts).max() < 1e-12
    assert abs(int(got[5][1]) - 35) <= 2
    # random access by time picks the nearest frame
    t, img = r.frame_at(ts[17] + 0.001)
    assert t == pytest.approx(ts[17], abs=1e-12)
    assert abs(int(img[0, 0, 0]) - (7 * 17) % 256) <= 2
    idx = [3, 11, 30]
    got = list(r.read_indices(idx))
    assert [g[0] for g in got] == idx and np.allclose([g[1] for g in got], ts[idx])


def _clip_with_click(path, codec, click_sample, start_s=0.0, channels=1, sr=SR):
    audio = np.zeros((sr * 3, channels), np.float32)
    audio[click_sample, 0] = 0.9
    if channels > 1:
        audio[:, 1] = 0.1 * np.sin(np.arange(len(audio)) * 0.01)
    ts = np.arange(60) / 30.0
    with VideoWriter(path, 64, 48, fps=30, audio_rate=sr, audio_codec=codec, audio_channels=channels) as w:
        for i, t in enumerate(ts):
            w.write_frame(np.zeros((48, 64, 3), np.uint8), t)
        w.write_audio(audio, start_s=start_s)
    return path


@pytest.mark.parametrize("start_s", [0.0, 0.25])
def test_pcm_click_at_exact_sample(tmp_path, start_s):
    click = 48000 + 123
    p = _clip_with_click(tmp_path / "pcm.mov", "pcm_s16le", click, start_s=start_s)
    a = read_audio(p)
    assert a.sample_rate == SR
    assert a.start_s == pytest.approx(start_s, abs=1 / SR / 2)
    # position on the video's timeline = start_s + index / sr
    got = a.start_s * SR + int(np.argmax(np.abs(a.mono())))
    assert round(got) == click + round(start_s * SR)


@pytest.mark.parametrize("sr", [48000, 44100])
def test_aac_click_within_one_sample(tmp_path, sr):
    click = sr + 777
    p = _clip_with_click(tmp_path / "aac.mp4", "aac", click, channels=2, sr=sr)
    a = read_audio(p)
    assert a.n_channels == 2 and a.sample_rate == sr
    x = np.abs(a.channel(0))
    peak = int(np.argmax(x))
    # sub-sample peak via a parabola through the three largest samples
    y0, y1, y2 = x[peak - 1], x[peak], x[peak + 1]
    frac = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    got = a.start_s * sr + peak + frac
    assert abs(got - click) <= 1.0


def test_timecode_roundtrip(tmp_path):
    p = tmp_path / "tc.mov"
    with VideoWriter(p, 64, 48, fps=25, timecode="01:02:03:04") as w:
        for i in range(5):
            w.write_frame(np.zeros((48, 64, 3), np.uint8), i / 25)
    assert read_timecode(p) == "01:02:03:04"
    assert read_timecode(write_video(tmp_path / "no_tc.mp4", _frames(3), [0, 0.04, 0.08])) is None


def test_no_audio_is_a_user_error(tmp_path):
    p = write_video(tmp_path / "silent.mp4", _frames(3), [0, 0.04, 0.08])
    with pytest.raises(UserError, match="no audio stream"):
        read_audio(p)


def test_truncated_and_garbage_videos_are_user_errors(tmp_path):
    ts = _irregular_times(30)
    good = write_video(tmp_path / "good.mp4", _frames(30, 120, 160), ts)
    data = good.read_bytes()
    (tmp_path / "trunc.mp4").write_bytes(data[: len(data) // 2])
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all" * 100)
    for name in ("trunc.mp4", "junk.mp4"):
        with pytest.raises(UserError) as e:
            VideoReader(tmp_path / name).info
        assert name in str(e.value)
    with pytest.raises(UserError, match="not found"):
        VideoReader(tmp_path / "missing.mp4").info


def test_writer_is_atomic_on_failure(tmp_path):
    p = tmp_path / "x.mp4"
    with pytest.raises(ValueError):
        with VideoWriter(p, 64, 48) as w:
            w.write_frame(np.zeros((48, 64, 3), np.uint8), 0.0)
            w.write_frame(np.zeros((48, 64, 3), np.uint8), 0.0)  # not increasing
    assert not p.exists() and not list(tmp_path.glob(".x.*"))
