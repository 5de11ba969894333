"""Reading videos with PyAV: exact presentation timestamps, random access, timecode.

Phones record variable frame rate, so a frame's time is its presentation timestamp
(float64 seconds on the container's timeline), never index / fps. Frame timestamps are
read from the demuxed packets (no decoding), so they are cheap and exact.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import av
import numpy as np

from mamma_kit.core.errors import UserError


def open_container(path: Path):
    """``av.open`` of a video or audio file; a missing, folder or unreadable path is a UserError."""
    if not path.exists():
        raise UserError(f"video not found: {path}", "check the path in the command or capture.toml")
    if path.is_dir():
        raise UserError(f"expected a video file, got a folder: {path}", "pass the video file itself")
    try:
        return av.open(str(path))
    except (av.error.InvalidDataError, av.error.EOFError) as e:
        raise UserError(
            f"{path.name} is not a readable video (corrupt, truncated or not a video: {getattr(e, 'strerror', None) or e})",
            "copy the file from the phone again or re-export it as .mp4/.mov",
        ) from None
    except av.error.FFmpegError as e:
        raise UserError(f"cannot open video {path}: {e}", "check the file is a complete .mp4/.mov") from None


def corrupt_error(path: Path, t: float | None, e: Exception) -> UserError:
    """The UserError for a decode failure ``e`` in ``path`` near time ``t`` (s; None: unknown)."""
    where = f" near t={t:.3f} s" if t is not None else ""
    return UserError(
        f"{path.name} is corrupt{where} ({type(e).__name__}: {e})",
        "copy the file from the phone again or re-export it",
    )


@dataclass
class VideoInfo:
    path: Path
    width: int
    height: int
    n_frames: int
    timestamps: np.ndarray  # (T,) float64 seconds, presentation order
    nominal_fps: float
    time_base: float
    timecode: str | None
    rotation_deg: int
    has_audio: bool

    @property
    def duration(self) -> float:
        """Span from the first frame's start to the last frame's end (s)."""
        if self.n_frames == 0:
            return 0.0
        if self.n_frames == 1:
            return 1.0 / self.nominal_fps if self.nominal_fps > 0 else 0.0
        last = np.median(np.diff(self.timestamps[-min(self.n_frames, 10):])) if self.n_frames > 1 else 0
        return float(self.timestamps[-1] - self.timestamps[0] + last)

    def to_dict(self) -> dict:
        return {
            "path": str(self.path), "width": self.width, "height": self.height,
            "n_frames": self.n_frames, "duration_s": self.duration, "nominal_fps": self.nominal_fps,
            "start_s": float(self.timestamps[0]) if self.n_frames else None,
            "timecode": self.timecode, "rotation_deg": self.rotation_deg, "has_audio": self.has_audio,
        }


class VideoReader:
    """A video file with exact frame timestamps.

    >>> r = VideoReader("cam0.mp4")
    >>> r.timestamps[:3]              # float64 seconds
    >>> for t, rgb_hw3 in r.frames(): ...
    >>> t, rgb_hw3 = r.frame_at(1.25) # nearest frame to 1.25 s
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._info: VideoInfo | None = None
        self._container = None

    # ---- metadata -----------------------------------------------------------------
    @property
    def info(self) -> VideoInfo:
        if self._info is None:
            self._info = self._probe()
        return self._info

    @property
    def timestamps(self) -> np.ndarray:
        return self.info.timestamps

    @property
    def n_frames(self) -> int:
        return self.info.n_frames

    @property
    def size(self) -> tuple[int, int]:
        return self.info.width, self.info.height

    def _probe(self) -> VideoInfo:
        c = open_container(self.path)
        try:
            if not c.streams.video:
                raise UserError(f"{self.path.name} has no video stream", "pass the camera's video file")
            vs = c.streams.video[0]
            tb = vs.time_base
            pts = []
            try:
                for pkt in c.demux(vs):
                    if pkt.pts is None or pkt.size == 0 or getattr(pkt, "is_discard", False):
                        continue
                    pts.append(pkt.pts)
            except av.error.FFmpegError as e:
                raise corrupt_error(self.path, float(pts[-1] * tb) if pts else None, e) from None
            ts = np.sort(np.asarray(pts, np.int64)).astype(np.float64) * float(tb)
            if len(ts) == 0:
                raise UserError(f"{self.path.name} holds no video frames (empty or truncated)",
                                "copy the file from the phone again")
            rate = vs.average_rate or vs.guessed_rate or vs.base_rate
            nominal = float(rate) if rate else (1.0 / np.median(np.diff(ts)) if len(ts) > 1 else 0.0)
            tc = vs.metadata.get("timecode")
            if tc is None:
                for s in c.streams:
                    if s.type == "data" and "timecode" in s.metadata:
                        tc = s.metadata["timecode"]
                        break
            return VideoInfo(
                path=self.path, width=vs.codec_context.width, height=vs.codec_context.height,
                n_frames=len(ts), timestamps=ts, nominal_fps=nominal, time_base=float(tb),
                timecode=tc, rotation_deg=self._rotation(), has_audio=bool(c.streams.audio),
            )
        finally:
            c.close()

    def _rotation(self) -> int:
        """Display rotation in degrees from the first frame's display matrix (0 if none)."""
        try:
            with av.open(str(self.path)) as c:
                for fr in c.decode(video=0):
                    return int(round(getattr(fr, "rotation", 0) or 0)) % 360
        except av.error.FFmpegError:
            return 0
        return 0

    # ---- frames -------------------------------------------------------------------
    def frames(self, start: float | None = None, end: float | None = None,
               fmt: str = "rgb24") -> Iterator[tuple[float, np.ndarray]]:
        """Yield (t, image_hw3 uint8) for frames with start <= t < end, in time order."""
        c = open_container(self.path)
        try:
            vs = c.streams.video[0]
            vs.thread_type = "AUTO"
            if start is not None and start > float(self.timestamps[0]):
                c.seek(int(start / float(vs.time_base)), stream=vs, backward=True, any_frame=False)
            t = None
            try:
                for fr in c.decode(vs):
                    if fr.pts is None:
                        continue
                    t = float(fr.pts * vs.time_base)
                    if start is not None and t < start - 1e-9:
                        continue
                    if end is not None and t >= end - 1e-9:
                        break
                    yield t, fr.to_ndarray(format=fmt)
            except av.error.FFmpegError as e:
                raise corrupt_error(self.path, t, e) from None
        finally:
            c.close()

    def frame_at(self, t: float, fmt: str = "rgb24") -> tuple[float, np.ndarray]:
        """The frame whose timestamp is nearest to ``t`` (seconds)."""
        ts = self.timestamps
        i = int(np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)) if len(ts) > 1 else 0
        if len(ts) > 1 and abs(ts[i - 1] - t) <= abs(ts[i] - t):
            i -= 1
        return self.frame_index(i, fmt)

    def frame_index(self, i: int, fmt: str = "rgb24") -> tuple[float, np.ndarray]:
        ts = self.timestamps
        if not 0 <= i < len(ts):
            raise IndexError(f"frame {i} outside 0..{len(ts) - 1}")
        for t, img in self.frames(start=float(ts[i]), fmt=fmt):
            return t, img
        raise corrupt_error(self.path, float(ts[i]), RuntimeError("frame could not be decoded"))

    def read_indices(self, indices: Sequence[int], fmt: str = "rgb24") -> Iterator[tuple[int, float, np.ndarray]]:
        """Yield (index, t, image) for sorted frame indices, decoding forward once."""
        want = sorted(set(int(i) for i in indices))
        if not want:
            return
        ts = self.timestamps
        targets = {float(ts[i]): i for i in want}
        k = 0
        for t, img in self.frames(start=float(ts[want[0]]), end=float(ts[want[-1]]) + 1e-6, fmt=fmt):
            i = targets.get(t)
            if i is None:  # tolerate float round-off
                j = int(np.argmin(np.abs(ts[want] - t)))
                if abs(ts[want[j]] - t) < 1e-7:
                    i = want[j]
            if i is not None:
                yield i, t, img
                k += 1
                if k == len(want):
                    return


def probe(path: str | Path) -> VideoInfo:
    return VideoReader(path).info


def read_timecode(path: str | Path) -> str | None:
    """The start timecode of a QuickTime/MP4 tmcd track ('HH:MM:SS:FF' or ';' for drop-frame)."""
    return VideoReader(path).info.timecode
