"""Audio extraction on the video's time origin.

Sync needs to know, to the sample, when each audio sample was recorded relative to the
video frames of the same file. ``read_audio`` returns the samples at their native rate
and ``start_s``: the container time of sample 0 (the same timeline as the video frames'
presentation timestamps). FFmpeg applies AAC priming and edit lists while decoding, so
the first decoded sample's timestamp is the right origin; gaps in the stream are filled
with silence so sample k sits at start_s + k / sample_rate.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import av
import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.video.reader import corrupt_error, open_container


@dataclass
class Audio:
    samples_nc: np.ndarray  # (N, C) float32 in [-1, 1]
    sample_rate: int
    start_s: float  # container time of sample 0
    codec: str = ""

    @property
    def n_samples(self) -> int:
        return self.samples_nc.shape[0]

    @property
    def n_channels(self) -> int:
        return self.samples_nc.shape[1]

    @property
    def duration(self) -> float:
        return self.n_samples / self.sample_rate

    def times(self) -> np.ndarray:
        return self.start_s + np.arange(self.n_samples) / self.sample_rate

    def mono(self) -> np.ndarray:
        return self.samples_nc.mean(axis=1)

    def channel(self, c: int) -> np.ndarray:
        return self.samples_nc[:, c]


def has_audio(path: str | Path) -> bool:
    c = open_container(Path(path))
    try:
        return bool(c.streams.audio)
    finally:
        c.close()


def read_audio(path: str | Path, stream_index: int = 0) -> Audio:
    """Decode an audio stream of a video file at its native sample rate.

    Raises a UserError if the file has no audio stream.
    """
    path = Path(path)
    c = open_container(path)
    try:
        if len(c.streams.audio) <= stream_index:
            raise UserError(
                f"{path.name} has no audio stream",
                "record with sound on, or sync by timecode (--method tmcd/ltc)",
            )
        st = c.streams.audio[stream_index]
        sr = st.codec_context.sample_rate or st.rate
        chunks: list[np.ndarray] = []
        start_pts = None  # in samples
        cursor = 0  # samples written so far
        t = None
        try:
            for fr in c.decode(st):
                x = fr.to_ndarray()
                # planar (C, n) or packed (1, n*C) -> (n, C)
                n = fr.samples
                ch = len(fr.layout.channels)
                if fr.format.is_planar:
                    x = x.reshape(ch, n).T
                else:
                    x = x.reshape(n, ch)
                x = _to_float(x)
                if fr.pts is not None:
                    pos = int(round(float(fr.pts * fr.time_base) * sr))
                    t = pos / sr
                    if start_pts is None:
                        start_pts = pos
                    gap = pos - (start_pts + cursor)
                    if gap > 0:  # missing samples: keep the timeline, fill with silence
                        chunks.append(np.zeros((gap, ch), np.float32))
                        cursor += gap
                    elif gap < 0:  # overlap: drop what was already written
                        x = x[-gap:]
                chunks.append(x)
                cursor += len(x)
        except av.error.FFmpegError as e:
            raise corrupt_error(path, t, e) from None
        if not chunks:
            raise UserError(f"{path.name}: the audio stream holds no samples", "record with sound on")
        samples = np.concatenate(chunks, 0).astype(np.float32, copy=False)
        start = (start_pts or 0) / sr
        return Audio(samples, int(sr), float(start), st.codec_context.name)
    finally:
        c.close()


def _to_float(x: np.ndarray) -> np.ndarray:
    if x.dtype == np.float32 or x.dtype == np.float64:
        return x.astype(np.float32, copy=False)
    if x.dtype == np.int16:
        return x.astype(np.float32) / 32768.0
    if x.dtype == np.int32:
        return x.astype(np.float32) / 2147483648.0
    if x.dtype == np.uint8:
        return (x.astype(np.float32) - 128.0) / 128.0
    return x.astype(np.float32)
