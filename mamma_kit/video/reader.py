"""Reading videos with PyAV: exact presentation timestamps, random access, timecode.

Phones record variable frame rate, so a frame's time is its presentation timestamp
(float64 seconds on the container's timeline), never index / fps. Frame timestamps are
read from the demuxed packets (no decoding), so they are cheap and exact.

Frames come as a player shows them: turned by the file's display matrix (a portrait phone video
is stored landscape; video/orientation.py) and, for HLG or PQ HDR, tone-mapped to SDR
(video/colour.py). ``size`` is the displayed size; every stage works in that frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import av
import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.video.colour import hdr_to_sdr, transfer_of
from mamma_kit.video.orientation import Orientation, from_display_matrix


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
    width: int  # displayed (after the display rotation)
    height: int
    n_frames: int
    timestamps: np.ndarray  # (T,) float64 seconds, presentation order
    nominal_fps: float
    time_base: float
    timecode: str | None
    rotation_deg: int  # clockwise turn from stored to displayed frames (0, 90, 180, 270)
    has_audio: bool
    mirrored: bool = False  # displayed frames are mirrored (after the turn)
    rotation_from: str = "file"  # "file" (its display matrix) or "capture.toml" (an override)
    stored_size: tuple[int, int] = (0, 0)  # width, height as the codec stores them
    codec: str = ""
    bit_depth: int = 8
    transfer: str = "sdr"  # "sdr", "hlg" or "pq" (HDR is tone-mapped to SDR when read)

    @property
    def orientation(self) -> Orientation:
        return Orientation(self.rotation_deg, self.mirrored)

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
            "timecode": self.timecode, "rotation_deg": self.rotation_deg, "mirrored": self.mirrored,
            "rotation_from": self.rotation_from, "stored_size": list(self.stored_size), "codec": self.codec,
            "bit_depth": self.bit_depth, "transfer": self.transfer, "has_audio": self.has_audio,
        }

    def describe(self) -> str:
        """One line for a user: displayed size, rotation, codec and HDR."""
        turn = (f", shown turned {self.rotation_deg} deg{' and mirrored' if self.mirrored else ''} "
                f"({'capture.toml' if self.rotation_from != 'file' else 'its display matrix'}; stored "
                f"{self.stored_size[0]}x{self.stored_size[1]})") if not self.orientation.is_identity else ""
        hdr = f", HDR {self.transfer.upper()} (tone-mapped to SDR)" if self.transfer != "sdr" else ""
        return (f"{self.width}x{self.height}{turn}, {self.codec} {self.bit_depth}-bit{hdr}, "
                f"{self.nominal_fps:.3g} fps, {self.n_frames} frames")


class VideoReader:
    """A video file with exact frame timestamps.

    >>> r = VideoReader("cam0.mp4")
    >>> r.timestamps[:3]              # float64 seconds
    >>> for t, rgb_hw3 in r.frames(): ...
    >>> t, rgb_hw3 = r.frame_at(1.25) # nearest frame to 1.25 s
    """

    def __init__(self, path: str | Path, rotation: int | None = None):
        """``rotation``: the clockwise turn (0, 90, 180, 270) that shows the stored frames upright,
        in place of the file's display matrix (capture.toml's per-camera ``rotation``); None: the
        file's own."""
        self.path = Path(path)
        self.rotation = rotation
        self._info: VideoInfo | None = None

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
            w, h = vs.codec_context.width, vs.codec_context.height
            shown, trc, depth = self._first_frame()
            src = "file"
            if self.rotation is not None:
                shown, src = Orientation(int(self.rotation) % 360), "capture.toml"
            dw, dh = shown.displayed_size(w, h)
            return VideoInfo(
                path=self.path, width=dw, height=dh, n_frames=len(ts), timestamps=ts, nominal_fps=nominal,
                time_base=float(tb), timecode=tc, rotation_deg=shown.cw, has_audio=bool(c.streams.audio),
                mirrored=shown.mirror, rotation_from=src, stored_size=(w, h), codec=vs.codec_context.name,
                bit_depth=depth, transfer=trc,
            )
        finally:
            c.close()

    def _first_frame(self) -> tuple[Orientation, str, int]:
        """The first frame's display orientation, transfer ("sdr", "hlg", "pq") and bits per sample."""
        try:
            with av.open(str(self.path)) as c:
                for fr in c.decode(video=0):
                    m9 = _display_matrix_of(fr)
                    depth = max((comp.bits for comp in fr.format.components), default=8)
                    return from_display_matrix(m9), transfer_of(fr.color_trc), int(depth)
        except av.error.FFmpegError:
            pass
        return Orientation(), "sdr", 8

    # ---- frames -------------------------------------------------------------------
    def working_size(self, max_side: int | None) -> tuple[int, int]:
        """The displayed (width, height) scaled so the longer side is at most ``max_side``."""
        w, h = self.size
        if not max_side or max(w, h) <= max_side:
            return w, h
        s = max_side / max(w, h)
        return max(1, round(w * s)), max(1, round(h * s))

    def frames(self, start: float | None = None, end: float | None = None,
               fmt: str = "rgb24", max_side: int | None = None) -> Iterator[tuple[float, np.ndarray]]:
        """Yield (t, image_hw3 uint8) for frames with start <= t < end, in time order, as displayed
        (turned, HDR tone-mapped); ``fmt`` "rgb24" or "gray" (any PyAV format for SDR files).
        ``max_side``: frames scaled down (area-averaged, while converting from YUV: one pass) so
        their longer side is at most this (working_size); a model that works at a fixed size does
        not pay for a 4K frame's pixels."""
        info = self.info
        shown, hdr = info.orientation, info.transfer if info.transfer != "sdr" else None
        ww, wh = self.working_size(max_side)
        scale = None if (ww, wh) == self.size else shown.stored_size(ww, wh)
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
                    yield t, shown.apply(_pixels(fr, fmt, hdr, scale))
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


def _pixels(fr, fmt: str, hdr: str | None, size: tuple[int, int] | None = None) -> np.ndarray:
    """The decoded frame as a ``fmt`` array (scaled to the stored ``size`` (w, h) if given); HDR
    through the tone map (colour.py)."""
    kw = {} if size is None else {"width": size[0], "height": size[1], "interpolation": "AREA"}
    if hdr is None:
        return fr.to_ndarray(format=fmt, **kw)
    rgb = hdr_to_sdr(fr.to_ndarray(format="rgb48le", **kw), hdr)
    if fmt == "rgb24":
        return rgb
    if fmt == "gray":
        import cv2

        return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    raise ValueError(f"an HDR frame reads as rgb24 or gray, not {fmt}")


def probe(path: str | Path, rotation: int | None = None) -> VideoInfo:
    return VideoReader(path, rotation).info


def read_timecode(path: str | Path) -> str | None:
    """The start timecode of a QuickTime/MP4 tmcd track ('HH:MM:SS:FF' or ';' for drop-frame)."""
    return VideoReader(path).info.timecode


def _display_matrix_of(frame: av.VideoFrame) -> np.ndarray | None:
    """The frame's 3x3 display matrix as 9 int32, or None.

    PyAV changed how a frame's side data iterates: up to 18.1.0 it yields the entries, from 18.1.1
    (a Mapping) their types, each looked up in the container."""
    container = frame.side_data
    for item in container:
        sd = item if hasattr(item, "type") else container[item]
        if sd.type.name == "DISPLAYMATRIX":
            return np.frombuffer(bytes(sd), np.int32)
    return None
