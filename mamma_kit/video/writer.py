"""Writing H.264 or HEVC video with exact (variable) timestamps, AAC or PCM audio and a timecode.

Used by the synthetic renderer (so test captures are real phone-like files: HEVC Main10, HLG,
portrait frames stored landscape with a display matrix, as phones write them) and by the
report's overlay videos. The file appears atomically when the writer is closed.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import numpy as np

import os

from mamma_kit.core.io import temp_beside
from mamma_kit.video.colour import TRC_HLG, sdr_to_hlg
from mamma_kit.video.orientation import Orientation, display_matrix

CODECS = {"h264": "libx264", "hevc": "libx265"}
# AVColorPrimaries / AVColorSpace BT.2020 (non-constant luminance), AVColorRange MPEG (limited)
_BT2020, _RANGE_MPEG = 9, 1

# 90 kHz is the MPEG/QuickTime video clock; every timestamp is stored as an integer tick.
VIDEO_TIME_BASE = Fraction(1, 90000)


class VideoWriter:
    """Write frames at given timestamps, plus optional audio and tmcd timecode.

    >>> with VideoWriter("cam0.mp4", 640, 480, fps=30, audio_rate=48000) as w:
    ...     w.write_frame(rgb_hw3, t=0.0)
    ...     w.write_audio(samples_nc, start_s=0.0)

    Timestamps are rounded to 1/90000 s. ``audio_codec`` is "aac" (phones) or
    "pcm_s16le" (needs a .mov container). ``timecode`` 'HH:MM:SS:FF' writes a tmcd track.
    ``codec`` "h264" (8-bit) or "hevc" with ``bit_depth`` 8 or 10; ``hlg`` writes HLG BT.2020
    (10-bit HEVC only; the RGB frames given are SDR and are converted, colour.sdr_to_hlg).
    ``orientation``: frames given as displayed are stored turned back, with the display matrix
    that shows them so (a portrait phone: Orientation(90), frames stored landscape).
    """

    def __init__(self, path: str | Path, width: int, height: int, fps: float = 30.0,
                 crf: int = 18, preset: str = "veryfast", audio_rate: int | None = None,
                 audio_channels: int = 1, audio_codec: str = "aac", timecode: str | None = None,
                 gop: int | None = None, codec: str = "h264", bit_depth: int = 8,
                 hlg: bool = False, orientation: Orientation | None = None):
        self.path = Path(path)
        self._tmp = temp_beside(self.path)
        tmp = self._tmp
        # movie_timescale: edit lists (e.g. audio that starts after the AAC priming) are stored in
        # movie ticks; the default 1 ms ticks shifted such audio by up to 1 ms (32 samples)
        fmt = _format_for(self.path)
        opts = {"movie_timescale": "90000"} if fmt in ("mp4", "mov") else {}
        self.container = av.open(str(tmp), "w", format=fmt, options=opts)
        fps_frac = Fraction(fps).limit_denominator(1001)
        if codec not in CODECS or bit_depth not in (8, 10) or (codec == "h264" and bit_depth != 8):
            raise ValueError(f"codec {codec} at {bit_depth} bits: use h264 (8) or hevc (8 or 10)")
        if hlg and bit_depth != 10:
            raise ValueError("HLG needs 10-bit video")
        self.orientation = orientation or Orientation()
        self.hlg = hlg
        vs = self.container.add_stream(CODECS[codec], rate=fps_frac)
        vs.width, vs.height = self.orientation.stored_size(int(width), int(height))
        vs.pix_fmt = "yuv420p10le" if bit_depth == 10 else "yuv420p"
        vs.time_base = VIDEO_TIME_BASE
        vs.codec_context.time_base = VIDEO_TIME_BASE
        if codec == "hevc":
            opts = {"crf": str(crf), "preset": preset, "x265-params": "bframes=0:log-level=error"}
            if fmt == "mov":
                vs.codec_tag = "hvc1"  # what iPhones write (and Apple's players need)
        else:
            opts = {"crf": str(crf), "preset": preset, "bf": "0"}
        if gop:
            opts["g"] = str(gop)
        vs.options = opts
        if hlg:
            cc = vs.codec_context
            cc.color_primaries, cc.colorspace, cc.color_trc, cc.color_range = _BT2020, _BT2020, TRC_HLG, _RANGE_MPEG
        if timecode:
            vs.metadata["timecode"] = timecode
        if not self.orientation.is_identity:
            vs.set_display_matrix([int(x) for x in display_matrix(self.orientation)])
        self.vs = vs
        self.as_ = None
        self.audio_rate = audio_rate
        self.audio_channels = audio_channels
        if audio_rate:
            layout = {1: "mono", 2: "stereo"}.get(audio_channels, f"{audio_channels}c")
            codec = audio_codec
            a = self.container.add_stream(codec, rate=int(audio_rate))
            a.layout = layout
            if codec == "aac":
                a.bit_rate = 192000 * audio_channels
                a.options = {"aac_coder": "fast"}  # 2x faster than the default two-loop search
            a.time_base = Fraction(1, int(audio_rate))
            self.as_ = a
            self._audio_fmt = "s16" if codec.startswith("pcm_s16") else ("fltp" if codec == "aac" else "flt")
        self._last_pts = -1
        self._audio_next = None
        self._closed = False

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close(ok=exc_type is None)

    def write_frame(self, rgb_hw3: np.ndarray, t: float) -> None:
        """Encode one RGB uint8 frame at presentation time ``t`` seconds (strictly increasing)."""
        pts = int(round(t / VIDEO_TIME_BASE))
        if pts <= self._last_pts:
            raise ValueError(f"timestamps must increase: {t} after {self._last_pts * VIDEO_TIME_BASE}")
        self._last_pts = pts
        stored = self.orientation.unapply(np.asarray(rgb_hw3, np.uint8))
        if self.hlg:
            fr = av.VideoFrame.from_ndarray(sdr_to_hlg(stored), format="rgb48le")
            fr.colorspace, fr.color_primaries, fr.color_trc, fr.color_range = _BT2020, _BT2020, TRC_HLG, _RANGE_MPEG
            fr = fr.reformat(format=self.vs.pix_fmt, dst_colorspace=_BT2020)
            fr.color_primaries, fr.color_trc, fr.color_range = _BT2020, TRC_HLG, _RANGE_MPEG
        else:
            fr = av.VideoFrame.from_ndarray(np.ascontiguousarray(stored), format="rgb24")
        fr.pts = pts
        fr.time_base = VIDEO_TIME_BASE
        for p in self.vs.encode(fr):
            self.container.mux(p)

    def write_audio(self, samples_nc: np.ndarray, start_s: float | None = None, block: int = 1024) -> None:
        """Append audio samples (N,) or (N, C) float in [-1, 1]; ``start_s`` places the first one."""
        if self.as_ is None:
            raise ValueError("writer was created without audio_rate")
        x = np.asarray(samples_nc, np.float32)
        if x.ndim == 1:
            x = x[:, None]
        if x.shape[1] != self.audio_channels:
            raise ValueError(f"expected {self.audio_channels} channels, got {x.shape[1]}")
        if start_s is not None:
            pos = int(round(start_s * self.audio_rate))
            if pos < 0:  # samples before the container origin are dropped
                x = x[-pos:]
                pos = 0
            self._audio_next = pos
        elif self._audio_next is None:
            self._audio_next = 0
        x = np.clip(x, -1, 1)
        for k in range(0, len(x), block):
            chunk = x[k:k + block]
            if self._audio_fmt == "s16":
                arr = (chunk * 32767).round().astype(np.int16).reshape(1, -1)
            elif self._audio_fmt == "fltp":
                arr = np.ascontiguousarray(chunk.T)
            else:
                arr = np.ascontiguousarray(chunk.reshape(1, -1))
            fr = av.AudioFrame.from_ndarray(arr, format=self._audio_fmt, layout=self.as_.layout.name)
            fr.sample_rate = self.audio_rate
            fr.pts = self._audio_next
            fr.time_base = Fraction(1, self.audio_rate)
            self._audio_next += len(chunk)
            for p in self.as_.encode(fr):
                self.container.mux(p)

    def close(self, ok: bool = True) -> None:
        """Flush the encoders and move the file into place (or discard it if not ``ok``)."""
        if self._closed:
            return
        self._closed = True
        try:
            if ok:
                for p in self.vs.encode():
                    self.container.mux(p)
                if self.as_ is not None:
                    for p in self.as_.encode():
                        self.container.mux(p)
            self.container.close()
            if ok:
                os.replace(self._tmp, self.path)
        finally:
            if self._tmp.exists():
                self._tmp.unlink()


def _format_for(path: Path) -> str:
    ext = path.suffix.lower()
    return {".mov": "mov", ".mp4": "mp4", ".m4v": "mp4", ".mkv": "matroska"}.get(ext, "mp4")


def write_video(path: str | Path, frames_thw3, timestamps, fps: float | None = None, **kw) -> Path:
    """Write a whole clip at once (convenience over :class:`VideoWriter`)."""
    frames = list(frames_thw3) if not isinstance(frames_thw3, np.ndarray) else frames_thw3
    ts = np.asarray(timestamps, float)
    if fps is None:
        fps = 1.0 / np.median(np.diff(ts)) if len(ts) > 1 else 30.0
    h, w = frames[0].shape[:2]
    with VideoWriter(path, w, h, fps=fps, **kw) as wr:
        for img, t in zip(frames, ts):
            wr.write_frame(img, float(t))
    return Path(path)
