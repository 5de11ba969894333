"""Synthetic camera audio: what each camera's microphone records in a scene.

A scene holds clap events (reference time + 3D position), microphones (one per camera, at
the camera's position), each camera's clock model (core.clock: t_ref = (1 + rate) * t_cam
+ offset, camera time = the video's container time, 0 = start of recording) and, optionally,
an LTC timecode generator on the reference clock fed into one audio channel.

``render_camera_audio`` returns, per camera, float32 samples (N, C) and ``start_s``: the
container time of sample 0 (write them with ``VideoWriter.write_audio(samples, start_s)``).
Sample k is recorded at camera time start_s + k / sr, i.e. the audio runs on the camera's
(drifting) clock like the video does.

What reaches each microphone from a clap emitted at reference time T from position P:
the clap waveform delayed by |P - mic| / 343 m/s (fractional, band-limited delay), scaled by
1/distance, convolved with a room impulse response that differs per microphone (direct
sound + ground reflection from an image source + random early reflections + an exponentially
decaying noise tail with the given RT60), plus white noise at the given SNR.

The LTC encoder (SMPTE 12M: 80-bit frames, biphase mark, BCD time, drop-frame, user bits,
polarity-correction bit, sync word) renders the generator's square wave on the reference
clock and samples it on the camera's clock with box-filter anti-aliasing (zero phase, so a
transition sits exactly where the clock model puts it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import gcd
from typing import Mapping, Sequence

import numpy as np
from scipy import signal

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.timecode import (frames_to_timecode, nominal_rate, parse_timecode, rate_fraction,
                                     timecode_to_frames)

SPEED_OF_SOUND = 343.0  # m/s at about 20 degrees C
SYNC_WORD_BITS = np.array([0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 1], np.uint8)  # bits 64..79


# ---------------------------------------------------------------------------------------
# scene description
@dataclass
class Clap:
    """A hand clap emitted at reference time ``t_ref`` (s) from ``position`` (m, world)."""
    t_ref: float
    position: tuple[float, float, float] = (0.0, 0.0, 1.3)
    level: float = 0.5  # peak amplitude of the direct sound at 1 m


@dataclass
class Microphone:
    """One camera's microphone.

    ``clock``: the camera's clock model (camera/container time -> reference time).
    ``duration_s``: length of the recorded audio in camera seconds.
    ``audio_start_s``: container time of the first audio sample (phones start audio a few
    ms before or after the first video frame).
    """
    position: tuple[float, float, float]
    clock: ClockModel = field(default_factory=ClockModel)
    duration_s: float = 10.0
    audio_start_s: float = 0.0
    sample_rate: int | None = None  # None: the rate passed to render_camera_audio


@dataclass
class Ambient:
    """A continuous sound common to all microphones: music from a loudspeaker at ``position``
    (a new chord of three tones every ``note_s`` seconds, soft 15 ms attacks so the notes are
    not mistaken for claps). ``level``: rms at 1 m."""
    position: tuple[float, float, float] = (6.0, 0.0, 1.2)
    level: float = 0.03
    note_s: float = 0.2
    seed: int = 7


def ambient_signal(t_emit: np.ndarray, amb: Ambient) -> np.ndarray:
    """The loudspeaker's output at emission times ``t_emit`` (s, reference clock), evaluated
    analytically so every microphone's delay and clock are exact."""
    t = np.asarray(t_emit, float)
    k = np.floor(t / amb.note_s).astype(np.int64)
    # pitches from a hash of the note index, so they do not depend on the range asked for
    f = np.stack([_note_freq(k, amb.seed, j) for j in range(3)], 1)
    tau = t - k * amb.note_s
    env = np.minimum(tau / 0.015, 1.0) * np.exp(-tau / (0.6 * amb.note_s))
    y = np.sum(np.sin(2 * np.pi * f * t[:, None]), axis=1) * env
    return (amb.level * y / 0.9).astype(np.float64)


def _note_freq(k: np.ndarray, seed: int, j: int) -> np.ndarray:
    """A pseudo-random pitch (150-2500 Hz, log-uniform) for note k, voice j: a hash of (k, j)."""
    h = (k.astype(np.uint64) * np.uint64(2654435761) + np.uint64(seed * 97 + j * 7919)) % np.uint64(1 << 31)
    h = (h * np.uint64(1103515245) + np.uint64(12345)) % np.uint64(1 << 31)
    u = h.astype(float) / float(1 << 31)
    return 150.0 * (2500.0 / 150.0) ** u


@dataclass
class Reverb:
    """Room impulse response parameters (drawn independently for every microphone).

    rt60_s: decay time of the diffuse tail; drr_db: direct-to-reverberant energy ratio of the
    tail; ground: add the floor reflection (image source at -z) with this reflection
    coefficient (0 = none); n_early: random early reflections within ``early_s`` after the
    direct sound, gains up to ``early_gain``.
    """
    rt60_s: float = 0.0
    drr_db: float = 60.0
    ground: float = 0.0
    n_early: int = 0
    early_s: tuple[float, float] = (0.003, 0.02)
    early_gain: float = 0.5

    @classmethod
    def preset(cls, name: "str | Reverb | None") -> "Reverb":
        if isinstance(name, Reverb):
            return name
        name = (name or "none").lower()
        if name == "none":
            return cls()
        if name == "weak":  # outdoors: a hard floor and a faint tail
            return cls(rt60_s=0.1, drr_db=20.0, ground=0.3, n_early=2, early_s=(0.005, 0.02), early_gain=0.15)
        if name == "strong":  # a furnished room
            return cls(rt60_s=0.4, drr_db=3.0, ground=0.6, n_early=8, early_s=(0.002, 0.02), early_gain=0.6)
        raise ValueError(f"unknown reverb preset {name!r} (none, weak, strong)")


@dataclass
class LtcSpec:
    """An LTC generator running on the reference clock, recorded on one channel.

    Frame ``start_tc`` begins at reference time ``t_ref_start``; frames run at the true rate of
    ``fps`` (23.976, 24, 25, 29.97, 30, 47.952, 48, 50, 59.94, 60; above 30 fps one LTC word
    carries a frame pair, SMPTE 12-1). ``user_bits``: 32-bit value
    repeated in every frame. ``shift_s``: per-camera generator error (a mis-jammed box).
    """
    fps: float = 25.0
    start_tc: str = "01:00:00:00"
    t_ref_start: float = 0.0
    drop_frame: bool = False
    user_bits: int = 0
    level: float = 0.3
    channel: int = 1
    shift_s: Mapping[str, float] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------
# clap waveform, impulse response, fractional delay
def clap_waveform(sample_rate: int, rng: np.random.Generator, duration_s: float = 0.004,
                  attack_s: float = 0.0003) -> np.ndarray:
    """A hand clap: band-limited noise burst (about 0.5-8 kHz) with a sharp attack and an
    exponential decay of ``duration_s`` (-40 dB); peak 1. Zero-padded at both ends."""
    n = int(np.ceil(duration_s * 1.5 * sample_rate))
    pad = 32
    noise = rng.standard_normal(n + 2 * pad)
    f = np.fft.rfftfreq(len(noise), 1 / sample_rate)
    band = np.exp(-0.5 * (np.log(np.maximum(f, 1.0) / 2000.0) / 0.9) ** 2)  # log-normal around 2 kHz
    noise = np.fft.irfft(np.fft.rfft(noise) * band, len(noise))[pad:pad + n]
    t = np.arange(n) / sample_rate
    env = np.minimum(t / attack_s, 1.0) * np.exp(-np.maximum(t - attack_s, 0) * (np.log(100) / duration_s))
    w = noise * env
    w /= np.abs(w).max()
    return np.r_[np.zeros(pad), w, np.zeros(pad)]  # leading zeros: onset sits at index `pad`


CLAP_PAD = 32  # leading zeros of clap_waveform: its onset sample
SOURCE_RATE = 96000  # claps are made at this rate, then resampled to each microphone's


def room_impulse_response(sample_rate: int, reverb: Reverb, rng: np.random.Generator,
                          ground_delay_s: float | None = None, ground_gain: float = 1.0) -> np.ndarray:
    """Impulse response relative to the direct sound (h[0] = 1)."""
    tail_s = 1.2 * reverb.rt60_s if reverb.rt60_s > 0 else 0.0
    n = max(int(np.ceil(max(tail_s, reverb.early_s[1] if reverb.n_early else 0, ground_delay_s or 0) * sample_rate)) + 2, 1)
    h = np.zeros(n)
    h[0] = 1.0
    if reverb.ground > 0 and ground_delay_s is not None:
        _add_frac(h, np.array([1.0]), ground_delay_s * sample_rate, reverb.ground * ground_gain)
    if reverb.n_early:
        d = rng.uniform(*reverb.early_s, reverb.n_early) * sample_rate
        g = rng.uniform(0.2, 1.0, reverb.n_early) * reverb.early_gain * rng.choice([-1, 1], reverb.n_early)
        for di, gi in zip(d, g):
            _add_frac(h, np.array([1.0]), di, gi)
    if reverb.rt60_s > 0:
        t = np.arange(n) / sample_rate
        start = int(0.002 * sample_rate)
        tail = rng.standard_normal(n) * np.exp(-np.log(1000) * t / reverb.rt60_s)
        tail[:start] *= np.linspace(0, 1, start)  # diffuse field builds up
        e_tail = np.sum(tail ** 2)
        tail *= np.sqrt(10 ** (-reverb.drr_db / 10) / max(e_tail, 1e-30))  # direct energy is 1
        h += tail
    return h


def _add_frac(out: np.ndarray, sig: np.ndarray, pos: float, gain: float = 1.0) -> None:
    """out[pos + k] += gain * sig[k] with a band-limited fractional delay (windowed sinc, 32 taps)."""
    i0 = int(np.floor(pos))
    frac = pos - i0
    if abs(frac) < 1e-12:
        kern = np.array([1.0])
        lo = i0
    else:
        half = 16
        k = np.arange(-half + 1, half + 1)  # taps at offsets relative to i0
        x = k - frac
        L = half + 1  # Blackman window evaluated at the continuous tap offsets
        kern = np.sinc(x) * (0.42 + 0.5 * np.cos(np.pi * x / L) + 0.08 * np.cos(2 * np.pi * x / L))
        lo = i0 - half + 1
    y = np.convolve(sig, kern) * gain
    a, b = lo, lo + len(y)
    ya, yb = max(0, -a), len(y) - max(0, b - len(out))
    if yb > ya:
        out[max(a, 0):min(b, len(out))] += y[ya:yb]


# ---------------------------------------------------------------------------------------
# LTC (SMPTE 12M linear timecode) encoder
def _bcd(value: int, n_bits: int) -> list[int]:
    return [(value >> i) & 1 for i in range(n_bits)]


def ltc_frame_bits(frame_count: int, fps: float, drop_frame: bool = False, user_bits: int = 0,
                   color_frame: bool = False) -> np.ndarray:
    """The 80 bits (bit 0 first) of the LTC frame with label ``frame_count`` frames since
    00:00:00:00 at ``fps``."""
    tc = frames_to_timecode(frame_count, fps, drop_frame)
    ub = [(user_bits >> (4 * g)) & 0xF for g in range(8)]  # user-bit groups 1..8
    b = np.zeros(80, np.uint8)
    b[0:4] = _bcd(tc.frames % 10, 4)
    b[4:8] = _bcd(ub[0], 4)
    b[8:10] = _bcd(tc.frames // 10, 2)
    b[10] = drop_frame
    b[11] = color_frame
    b[12:16] = _bcd(ub[1], 4)
    b[16:20] = _bcd(tc.seconds % 10, 4)
    b[20:24] = _bcd(ub[2], 4)
    b[24:27] = _bcd(tc.seconds // 10, 3)
    b[28:32] = _bcd(ub[3], 4)
    b[32:36] = _bcd(tc.minutes % 10, 4)
    b[36:40] = _bcd(ub[4], 4)
    b[40:43] = _bcd(tc.minutes // 10, 3)
    b[44:48] = _bcd(ub[5], 4)
    b[48:52] = _bcd(tc.hours % 10, 4)
    b[52:56] = _bcd(ub[6], 4)
    b[56:58] = _bcd(tc.hours // 10, 2)
    b[60:64] = _bcd(ub[7], 4)
    b[64:80] = SYNC_WORD_BITS
    # polarity correction: bit 59 at 25 fps, bit 27 otherwise; makes the count of zeros even
    pc = 59 if nominal_rate(fps) == 25 else 27
    if (80 - int(b.sum())) % 2:
        b[pc] = 1
    return b


def _word_rate(spec: LtcSpec):
    """(LTC words per second, label of the first word): above 30 fps one word per frame pair."""
    full = rate_fraction(spec.fps)
    n_full = timecode_to_frames(parse_timecode(spec.start_tc) if isinstance(spec.start_tc, str)
                                else spec.start_tc, full)
    if full > 31:
        return full / 2, n_full // 2
    return full, n_full


def ltc_transition_times(t0: float, t1: float, spec: LtcSpec) -> np.ndarray:
    """Reference times of every level transition of the LTC signal between t0 and t1."""
    rate, n_start = _word_rate(spec)
    fps = float(rate)
    k0 = int(np.floor((t0 - spec.t_ref_start) * fps)) - 1
    k1 = int(np.ceil((t1 - spec.t_ref_start) * fps)) + 1
    ks = np.arange(k0, k1 + 1)
    bits_kb = np.stack([ltc_frame_bits(n_start + int(k), rate, spec.drop_frame, spec.user_bits) for k in ks])
    t_bit = 1.0 / (80.0 * fps)
    # boundaries: every bit start; mid-bit: every one
    starts_kb = spec.t_ref_start + (ks[:, None] * 80 + np.arange(80)[None, :]) * t_bit
    mids = (starts_kb + 0.5 * t_bit)[bits_kb == 1]
    tr = np.sort(np.r_[starts_kb.ravel(), mids])
    return tr[(tr >= t0 - t_bit) & (tr <= t1 + t_bit)]


def render_ltc(t_ref_n: np.ndarray, dt_ref: float, spec: LtcSpec, shift_s: float = 0.0) -> np.ndarray:
    """Sample the LTC square wave at reference times ``t_ref_n`` (spacing ``dt_ref``), each
    sample the mean level over [t - dt/2, t + dt/2] (zero-phase anti-aliasing)."""
    t = np.asarray(t_ref_n, float) - shift_s
    tr = ltc_transition_times(float(t.min()) - dt_ref, float(t.max()) + dt_ref, spec)
    lo, hi = t - dt_ref / 2, t + dt_ref / 2
    c_lo = np.searchsorted(tr, lo)
    c_hi = np.searchsorted(tr, hi)
    level = np.where(c_lo % 2 == 0, 1.0, -1.0)  # level just after `lo`
    y = level.copy()
    one = c_hi - c_lo == 1
    if np.any(one):
        ttr = tr[np.minimum(c_lo[one], len(tr) - 1)]
        a = (ttr - lo[one]) / dt_ref
        y[one] = level[one] * (2 * a - 1)
    return (spec.level * y).astype(np.float32)


# ---------------------------------------------------------------------------------------
# the scene as each camera hears it
def arrival_times(mics: Mapping[str, Microphone], claps: Sequence[Clap],
                  speed_of_sound: float = SPEED_OF_SOUND) -> dict[str, np.ndarray]:
    """Per camera: camera (container) time at which each clap's direct sound arrives (K,)."""
    out = {}
    for name, m in mics.items():
        t = [m.clock.to_cam(c.t_ref + np.linalg.norm(np.subtract(c.position, m.position)) / speed_of_sound)
             for c in claps]
        out[name] = np.asarray(t, float)
    return out


def render_camera_audio(mics: Mapping[str, Microphone], claps: Sequence[Clap] = (), *,
                        sample_rate: int = 48000, snr_db: float = 10.0, reverb: "str | Reverb | None" = "weak",
                        ltc: LtcSpec | None = None, n_channels: int | None = None, seed: int = 0,
                        speed_of_sound: float = SPEED_OF_SOUND, ambient: Ambient | None = None
                        ) -> dict[str, tuple[np.ndarray, float]]:
    """Render each camera's audio track.

    mics: {camera: Microphone(position, clock, duration_s, audio_start_s)}.
    claps: clap events; reverb: "none" | "weak" (outdoor) | "strong" (room) | Reverb.
    snr_db: ratio of a clap's direct sound power (over its burst) to the noise power, at each
    microphone (the loudest clap at that microphone sets the noise level).
    ltc: an LTC generator recorded on channel ``ltc.channel`` (claps and noise go on channel 0;
    other channels get the clap sound too). n_channels defaults to 1, or ltc.channel + 1.
    ambient: optional music from a loudspeaker, heard by every microphone (delay, 1/r, reverb).
    Returns {camera: (samples (N, C) float32 in [-1, 1], start_s)}.
    """
    rv = Reverb.preset(reverb)
    if n_channels is None:
        n_channels = 1 if ltc is None else max(1, ltc.channel + 1)
    rng_root = np.random.default_rng(seed)
    out: dict[str, tuple[np.ndarray, float]] = {}
    arrivals = arrival_times(mics, claps, speed_of_sound)
    # one source sound per clap, made at 96 kHz and resampled to each microphone's rate
    sources96 = [clap_waveform(SOURCE_RATE, rng_root) for _ in claps]
    for ci, (name, m) in enumerate(mics.items()):
        rng = np.random.default_rng(rng_root.integers(1 << 62) + ci)
        sr = int(m.sample_rate or sample_rate)
        g = gcd(sr, SOURCE_RATE)
        sources = [signal.resample_poly(w, sr // g, SOURCE_RATE // g) for w in sources96]
        pad = CLAP_PAD * sr / SOURCE_RATE
        n = int(round(m.duration_s * sr))
        acoustic = np.zeros(n)
        burst_rms = []
        for k, c in enumerate(claps):
            dist = max(float(np.linalg.norm(np.subtract(c.position, m.position))), 0.3)
            gain = c.level / dist
            w = sources[k]
            core = w[int(pad):int(pad) + int(0.004 * sr)]
            burst_rms.append(gain * np.sqrt(np.mean(core ** 2)))
            # floor reflection: image source mirrored at z = 0
            img = np.array(c.position, float) * [1, 1, -1]
            d_img = float(np.linalg.norm(img - np.asarray(m.position, float)))
            h = room_impulse_response(sr, rv, rng, ground_delay_s=(d_img - dist) / speed_of_sound,
                                      ground_gain=dist / max(d_img, 1e-9))
            y = np.convolve(w, h)
            pos = (arrivals[name][k] - m.audio_start_s) * sr - pad
            _add_frac(acoustic, y, pos, gain)
        if ambient is not None:
            t_ref = m.clock.to_ref(m.audio_start_s + np.arange(n) / sr)
            d_a = max(float(np.linalg.norm(np.subtract(ambient.position, m.position))), 0.3)
            img = np.array(ambient.position, float) * [1, 1, -1]
            d_img = float(np.linalg.norm(img - np.asarray(m.position, float)))
            h = room_impulse_response(sr, rv, rng, ground_delay_s=(d_img - d_a) / speed_of_sound,
                                      ground_gain=d_a / max(d_img, 1e-9))
            music = ambient_signal(t_ref - d_a / speed_of_sound, ambient) / d_a
            acoustic += signal.fftconvolve(music, h)[:n]
        noise_rms = (max(burst_rms) if burst_rms else 0.05) / 10 ** (snr_db / 20)
        acoustic += rng.standard_normal(n) * noise_rms
        x = np.repeat(acoustic[:, None], n_channels, axis=1)
        if ltc is not None:
            t_cam = m.audio_start_s + np.arange(n) / sr
            t_ref = m.clock.to_ref(t_cam)
            x[:, ltc.channel] = render_ltc(t_ref, (1 + m.clock.rate) / sr, ltc,
                                           float(ltc.shift_s.get(name, 0.0)))
            x[:, ltc.channel] += rng.standard_normal(n) * 1e-3
        out[name] = (np.clip(x, -1, 1).astype(np.float32), float(m.audio_start_s))
    return out


def ltc_frame_starts(mic: Microphone, spec: LtcSpec, shift_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth of the LTC in one camera's recording: (word counts (F,), camera times of
    their starts (F,)) for every LTC word that starts and ends inside the audio (above 30 fps a
    word is a frame pair)."""
    rate, n_start = _word_rate(spec)
    fps = float(rate)
    t0 = float(mic.clock.to_ref(mic.audio_start_s))
    t1 = float(mic.clock.to_ref(mic.audio_start_s + mic.duration_s))
    k = np.arange(int(np.ceil((t0 - spec.t_ref_start - shift_s) * fps)),
                  int(np.floor((t1 - spec.t_ref_start - shift_s) * fps)))
    t_ref = spec.t_ref_start + shift_s + k / fps
    return n_start + k, mic.clock.to_cam(t_ref)


__all__ = ["SPEED_OF_SOUND", "Clap", "Microphone", "Reverb", "LtcSpec", "Ambient", "ambient_signal", "clap_waveform", "room_impulse_response",
           "ltc_frame_bits", "render_ltc", "arrival_times", "render_camera_audio", "ltc_frame_starts"]


# ---------------------------------------------------------------------------------------
# small phone-like capture workspaces for sync tests and benchmarks
def write_sync_workspace(root, *, n_cameras: int = 3, duration_s: float = 20.0, fps: float = 10.0,
                         size: tuple[int, int] = (64, 48), clap_times: Sequence[float] = (4.0, 15.0),
                         clocks: Sequence[ClockModel] | None = None, audio_start_s: Sequence[float] | None = None,
                         sample_rate: int | Sequence[int] = 48000, snr_db: float = 10.0,
                         reverb: "str | Reverb | None" = "weak", ltc: LtcSpec | None = None,
                         audio_codec: str = "aac", timecode: bool = False, radius: float = 4.5,
                         clap_positions_known: bool = True, vfr_jitter: float = 0.2, seed: int = 0,
                         audio: bool = True, ambient: Ambient | None = None,
                         timecode_shift_s: Mapping[str, float] | None = None) -> dict:
    """Write a capture workspace whose cameras hear claps (and LTC): videos/<cam>.mp4 (.mov for
    PCM) with H.264 frames at each camera's clock (variable frame rate: each interval jittered
    by +-vfr_jitter of a frame), the rendered audio (AAC by default), capture.toml,
    calibration.toml (cameras on a ring looking at the centre; microphones at the camera
    centres), gt/timing.toml (true clocks, reference = the scene clock) and, with
    ``timecode``, a tmcd start timecode at the video rate (01:00:00:00 = reference time 0,
    rounded to the first frame's nearest whole frame).
    Claps are at reference times ``clap_times`` from random points near the centre; with
    ``clap_positions_known`` they are written to capture.toml [settings.sync].
    Returns {"mics", "claps", "clocks", "videos", "frame_times"}.
    """
    from pathlib import Path

    from mamma_kit.core.calibfile import write_calibration
    from mamma_kit.core.camera import Camera, Rig
    from mamma_kit.core.io import write_toml
    from mamma_kit.core.timecode import frames_to_timecode
    from mamma_kit.core.timingfile import write_timing
    from mamma_kit.video import VideoWriter

    root = Path(root)
    rng = np.random.default_rng(seed)
    names = [f"cam{i}" for i in range(n_cameras)]
    if clocks is None:
        clocks = [ClockModel(float(rng.uniform(-1.5, 1.5)), float(rng.uniform(-150e-6, 150e-6))) for _ in names]
    if audio_start_s is None:
        audio_start_s = [float(rng.uniform(-0.03, 0.03)) for _ in names]
    srs = [sample_rate] * n_cameras if np.isscalar(sample_rate) else list(sample_rate)
    w, h = size
    f = 0.9 * w
    cams, mics = [], {}
    for i, n in enumerate(names):
        a = 2 * np.pi * i / n_cameras + 0.3
        C = np.array([radius * np.cos(a), radius * np.sin(a), 1.6])
        z = np.array([0, 0, 1.0]) - C
        z /= np.linalg.norm(z)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        cams.append(Camera(n, (w, h), np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1]]),
                           np.zeros(5), "radtan", R, -R @ C))
        mics[n] = Microphone(tuple(C), clocks[i], duration_s, audio_start_s[i], int(srs[i]))
    claps = [Clap(float(t), tuple(rng.uniform([-1.0, -1.0, 1.0], [1.0, 1.0, 1.6]))) for t in clap_times]
    rendered: dict = {}
    if audio:
        rendered = render_camera_audio(mics, claps, snr_db=snr_db, reverb=reverb, ltc=ltc, seed=seed, ambient=ambient)
    (root / "videos").mkdir(parents=True, exist_ok=True)
    ext = ".mov" if audio_codec.startswith("pcm") else ".mp4"
    videos, frame_times = {}, {}
    for i, n in enumerate(names):
        k = np.arange(int(duration_s * fps))
        jit = rng.uniform(-vfr_jitter, vfr_jitter, len(k)) / fps
        ts = np.round((k / fps + jit + 0.5 / fps) * 90000) / 90000  # on the 90 kHz clock
        ts = np.maximum.accumulate(ts)
        ts = ts[np.r_[True, np.diff(ts) > 0]]
        tc = None
        if timecode:
            t0_ref = float(clocks[i].to_ref(ts[0]))
            t0_ref += (timecode_shift_s or {}).get(n, 0.0)  # a camera whose clock was set wrong
            tc = str(frames_to_timecode(int(round((3600.0 + t0_ref) * fps)), fps))
        path = root / "videos" / f"{n}{ext}"
        kw = {}
        if audio:
            x, s0 = rendered[n]
            kw = dict(audio_rate=srs[i], audio_channels=x.shape[1], audio_codec=audio_codec)
        with VideoWriter(path, w, h, fps=fps, timecode=tc, **kw) as wr:
            img = np.zeros((h, w, 3), np.uint8)
            for j, t in enumerate(ts):
                img[:] = (j * 5) % 256
                wr.write_frame(img, float(t))
            if audio:
                wr.write_audio(x, start_s=s0)
        videos[n], frame_times[n] = path, ts
    cap = {"capture": {"name": "sync-test"}, "cameras": {n: {"video": f"videos/{videos[n].name}"} for n in names}}
    if clap_positions_known:
        cap["settings"] = {"sync": {"clap_positions": [list(c.position) for c in claps]}}
    write_toml(root / "capture.toml", cap)
    write_calibration(root / "calibration.toml", Rig(cams))
    write_timing(root / "gt" / "timing.toml", {n: ClockModel(c.offset, c.rate, "gt", 1.0) for n, c in zip(names, clocks)},
                 reference="scene", method="gt")
    return {"mics": mics, "claps": claps, "clocks": dict(zip(names, clocks)), "videos": videos,
            "frame_times": frame_times}
