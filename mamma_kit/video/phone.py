"""A video re-encoded the way a phone stores it: for tests and benchmarks on real footage.

``phone_copy`` writes what an upright phone writes for the same picture: the displayed frames
stored turned back (a portrait picture stored landscape) with the display matrix that shows them
upright, HEVC Main10 (optionally HLG BT.2020), a .mov, AAC audio, and frames dropped where asked
(each dropped frame leaves a gap in the timestamps, as a phone's encoder does when it falls
behind). The source's timestamps are kept, so the copy and the source show the same instants.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np

from mamma_kit.video.orientation import Orientation
from mamma_kit.video.reader import VideoReader
from mamma_kit.video.writer import VideoWriter

AUDIO_RATE = 48000


def phone_copy(src: str | Path, dst: str | Path, *, orientation: Orientation = Orientation(90), codec: str = "hevc",
               bit_depth: int = 10, hlg: bool = False, drop: Iterable[int] = (), crop: tuple[int, int] | None = None,
               frames: int | None = None, crf: int = 18, preset: str = "veryfast", audio: bool = True,
               seed: int = 0) -> Path:
    """Write ``dst`` from ``src``'s displayed frames. ``crop`` (width, height): keep the top-left
    part of each frame (a 1088-row source becomes the 1080 rows a phone stores); ``frames``: only
    the first ones; ``audio``: the source's audio, or quiet noise (48 kHz AAC) where it has none."""
    from mamma_kit.video.audio import read_audio

    rd = VideoReader(src)
    info = rd.info
    w, h = crop or (info.width, info.height)
    drop = set(int(i) for i in drop)
    n = info.n_frames if frames is None else min(frames, info.n_frames)
    sound = None
    if audio:
        if info.has_audio:
            a = read_audio(src)
            sound = (a.samples_nc, a.sample_rate, a.start_s)
        else:
            rng = np.random.default_rng(seed)
            dur = float(info.timestamps[n - 1] - info.timestamps[0]) + 1.0 / max(info.nominal_fps, 1.0)
            sound = (0.01 * rng.standard_normal((int(dur * AUDIO_RATE), 1)).astype(np.float32), AUDIO_RATE,
                     float(info.timestamps[0]))
    with VideoWriter(dst, w, h, fps=info.nominal_fps, crf=crf, preset=preset, codec=codec, bit_depth=bit_depth, hlg=hlg,
                     orientation=orientation, audio_rate=sound[1] if sound else None,
                     audio_channels=sound[0].shape[1] if sound else 1) as wr:
        if sound is not None:
            wr.write_audio(sound[0], start_s=sound[2])
        for i, (t, rgb) in enumerate(rd.frames(end=float(info.timestamps[n - 1]) + 1e-6)):
            if i not in drop:
                wr.write_frame(rgb[:h, :w], t)
    return Path(dst)
