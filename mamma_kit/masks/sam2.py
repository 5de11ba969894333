"""`--backend sam2`: SAM 2 video propagation with the user's checkpoint, in bounded chunks.

The `sam2` package (not a dependency of mamma-kit; `pip install sam2` and a checkpoint from its
authors) builds a video predictor: ``build_sam2_video_predictor(config, checkpoint, device)``,
``init_state(video_path, offload_video_to_cpu, offload_state_to_cpu)``,
``add_new_points_or_box`` / ``add_new_mask``, ``propagate_in_video``, ``reset_state``.

Loading a whole video into one inference state is what makes long takes run out of memory, so
the video is cut into chunks of ``chunk`` frames (a folder of JPEG frames each, written to a
temporary directory). Chunk k + 1 starts on the last frame of chunk k and every person is
conditioned there on the mask chunk k gave them, so ids carry across chunks; the video and the
state are offloaded to CPU inside a chunk. Memory is bounded by one chunk whatever the length.

Prompts: from a TOML file (boxes or clicks per person on a frame, see ``load_prompts``) or, by
default, from the builtin backend's detections (each builtin track's box on its first frame).
A chunk also starts at every prompt's frame so that each object is conditioned on the first
frame of the chunk it enters in.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_toml
from mamma_kit.core.tracks import MaskTracks
from mamma_kit.masks.base import CameraInput, MaskTrackBuilder, track_summary


@dataclass
class Prompt:
    camera: str
    frame: int
    track: int
    box: list[float] | None = None  # x1, y1, x2, y2 px
    points: list[list[float]] | None = None  # (n, 2) px
    labels: list[int] | None = None  # 1 positive, 0 negative click
    time_s: float | None = None  # alternative to frame: nearest frame to this camera time


def load_prompts(path: Path) -> list[Prompt]:
    """prompts.toml::

        [[cam0]]                  # one table per person and camera
        track = 0                 # the id this person's track gets
        frame = 0                 # frame index of that camera's video (or time_s = 1.25)
        box = [412, 160, 530, 610]
        [[cam0]]
        track = 1
        frame = 0
        points = [[700, 300], [705, 520]]
        labels = [1, 1]           # optional; 1 = on the person, 0 = not
    """
    data = read_toml(path, "prompts file")
    out: list[Prompt] = []
    for cam, items in data.items():
        if not isinstance(items, list):
            raise UserError(f"{Path(path).name}: '{cam}' must be an array of tables ([[{cam}]])",
                            "write one [[CAMERA]] table per person")
        for i, d in enumerate(items):
            where = f"{Path(path).name}: [[{cam}]] #{i + 1}"
            if "track" not in d:
                raise UserError(f"{where} has no 'track'", "give each person an integer track id")
            box, pts = d.get("box"), d.get("points")
            if (box is None) == (pts is None):
                raise UserError(f"{where} needs exactly one of 'box' or 'points'", "e.g. box = [x1, y1, x2, y2]")
            if box is not None and (len(box) != 4 or not box[2] > box[0] or not box[3] > box[1]):
                raise UserError(f"{where}: box must be [x1, y1, x2, y2] with x2 > x1, y2 > y1", "fix the box")
            labels = d.get("labels")
            if pts is not None:
                if not pts or any(len(p) != 2 for p in pts):
                    raise UserError(f"{where}: points must be [[x, y], ...]", "fix the points")
                labels = labels if labels is not None else [1] * len(pts)
                if len(labels) != len(pts):
                    raise UserError(f"{where}: {len(labels)} labels for {len(pts)} points", "one label per point")
            if "frame" not in d and "time_s" not in d:
                raise UserError(f"{where} has neither 'frame' nor 'time_s'", "add frame = 0")
            out.append(Prompt(str(cam), int(d.get("frame", -1)), int(d["track"]),
                              [float(v) for v in box] if box is not None else None,
                              [[float(a), float(b)] for a, b in pts] if pts is not None else None,
                              [int(v) for v in labels] if labels is not None else None,
                              float(d["time_s"]) if "time_s" in d else None))
    return out


def prompts_from_tracks(mt: MaskTracks) -> list[Prompt]:
    """A box prompt per track on the first frame it appears (builtin detections)."""
    out = []
    for k, tid in enumerate(mt.track_ids):
        ts = np.flatnonzero(mt.present[:, k])
        if len(ts):
            out.append(Prompt(mt.camera, int(ts[0]), int(tid), [float(v) for v in mt.boxes[ts[0], k]]))
    return out


def _to_numpy(x) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().float().cpu().numpy()
    return np.asarray(x)


@dataclass
class ChunkStats:
    chunks: int = 0
    max_frames_in_state: int = 0
    starts: list[int] = field(default_factory=list)


def chunk_starts(n_frames: int, chunk: int, prompt_frames: list[int]) -> list[int]:
    """First frames of the chunks: every chunk - 1 frames (one frame overlap) and at every prompt."""
    starts = set(range(0, max(n_frames - 1, 1), chunk - 1)) | {f for f in prompt_frames if 0 <= f < n_frames}
    return sorted(starts)


def run_chunked(predictor, frames_iter, n_frames: int, prompts: list[Prompt], chunk: int, builder: MaskTrackBuilder,
                workdir: Path, stats: ChunkStats | None = None) -> ChunkStats:
    """Propagate masks through the video chunk by chunk (see module doc).

    frames_iter yields (frame index, rgb image) in order; the predictor follows the sam2
    video-predictor interface.
    """
    import cv2

    stats = stats or ChunkStats()
    starts = chunk_starts(n_frames, chunk, [p.frame for p in prompts])
    ends = [min(n_frames, (starts[i + 1] + 1) if i + 1 < len(starts) else n_frames, s + chunk)
            for i, s in enumerate(starts)]
    by_frame: dict[int, list[Prompt]] = {}
    for p in prompts:
        by_frame.setdefault(p.frame, []).append(p)
    carry: dict[int, np.ndarray] = {}
    it = iter(frames_iter)
    buffered: dict[int, np.ndarray] = {}

    def frame(i: int) -> np.ndarray:
        while i not in buffered:
            j, img = next(it)
            buffered[j] = img
        return buffered[i]

    for s, e in zip(starts, ends):
        if e - s < 1:
            continue
        d = workdir / f"chunk_{s:07d}"
        d.mkdir(parents=True, exist_ok=True)
        for i in range(s, e):
            cv2.imwrite(str(d / f"{i - s:05d}.jpg"), cv2.cvtColor(frame(i), cv2.COLOR_RGB2BGR),
                        [cv2.IMWRITE_JPEG_QUALITY, 95])
        for i in [i for i in buffered if i < e - 1]:
            del buffered[i]  # keep only the overlap frame
        new = by_frame.get(s, [])
        if not carry and not new:
            shutil.rmtree(d, ignore_errors=True)
            continue
        state = predictor.init_state(video_path=str(d), offload_video_to_cpu=True, offload_state_to_cpu=True)
        stats.chunks += 1
        stats.starts.append(s)
        stats.max_frames_in_state = max(stats.max_frames_in_state, e - s)
        prompted = set()
        for p in new:
            if p.box is not None:
                predictor.add_new_points_or_box(inference_state=state, frame_idx=0, obj_id=p.track,
                                                box=np.asarray(p.box, np.float32))
            else:
                predictor.add_new_points_or_box(inference_state=state, frame_idx=0, obj_id=p.track,
                                                points=np.asarray(p.points, np.float32),
                                                labels=np.asarray(p.labels, np.int32))
            prompted.add(p.track)
        for obj, m in carry.items():
            if obj not in prompted:  # a new prompt for a person overrides the carried mask
                predictor.add_new_mask(inference_state=state, frame_idx=0, obj_id=obj, mask=m)
        last: dict[int, np.ndarray] = {}
        for fidx, obj_ids, logits in predictor.propagate_in_video(state):
            L = _to_numpy(logits)
            for obj, lg in zip(list(obj_ids), L):
                m = np.asarray(lg).reshape(lg.shape[-2:]) > 0.0
                t = s + int(fidx)
                if t > s or s == 0 or obj in prompted:  # the overlap frame was written by the chunk before
                    builder.add(t, int(obj), m, 1.0)
                if int(fidx) == e - s - 1:
                    last[int(obj)] = m
        carry = {o: m for o, m in last.items() if m.any()}
        if hasattr(predictor, "reset_state"):
            predictor.reset_state(state)
        del state
        shutil.rmtree(d, ignore_errors=True)
    return stats


class Sam2Backend:
    name = "sam2"

    def __init__(self, checkpoint: Path | None = None, config: str | None = None, prompts: Path | None = None,
                 chunk: int = 64, device: str = "cpu", predictor=None):
        if chunk < 2:
            raise UserError(f"--chunk {chunk} is too small", "use at least 2 frames per chunk")
        self.chunk, self.device = int(chunk), device
        self.prompts = load_prompts(Path(prompts)) if prompts is not None else None
        self._predictor = predictor
        self._built = predictor is None  # ours to wrap in torch.inference_mode
        if predictor is None:
            if checkpoint is None or config is None:
                raise UserError("--backend sam2 needs --sam2-checkpoint PATH and --sam2-config NAME",
                                "download a SAM 2 checkpoint from its authors and pass it with its config, "
                                "or use --backend builtin")
            if not Path(checkpoint).is_file():
                raise UserError(f"SAM 2 checkpoint not found: {checkpoint}", "check --sam2-checkpoint")
            try:
                import sam2  # noqa: F401
            except ImportError:
                raise UserError("--backend sam2 needs the 'sam2' package, which is not installed",
                                "pip install sam2 (it needs torchvision), or use --backend builtin") from None
            self.checkpoint, self.config = Path(checkpoint), str(config)

    @property
    def predictor(self):
        if self._predictor is None:
            from sam2.build_sam import build_sam2_video_predictor

            try:
                self._predictor = build_sam2_video_predictor(self.config, str(self.checkpoint), device=self.device)
            except Exception as e:  # noqa: BLE001 - hydra/torch raise many kinds
                raise UserError(f"SAM 2 could not load {self.checkpoint.name} with config {self.config} ({e})",
                                "pass the config that belongs to the checkpoint, e.g. "
                                "configs/sam2.1/sam2.1_hiera_t.yaml for sam2.1_hiera_tiny.pt") from None
        return self._predictor

    def camera_prompts(self, cam: CameraInput, times: np.ndarray) -> list[Prompt]:
        if self.prompts is None:
            from mamma_kit.masks.builtin import BuiltinBackend

            log.info(f"{cam.name}: sam2 prompts from builtin detections")
            mt, _ = BuiltinBackend().track_camera(cam)
            return prompts_from_tracks(mt)
        out = []
        for p in self.prompts:
            if p.camera != cam.name:
                continue
            if p.time_s is not None:
                p = Prompt(**{**p.__dict__, "frame": int(np.argmin(np.abs(times - p.time_s)))})
            if not 0 <= p.frame < len(times):
                raise UserError(f"prompt for {cam.name} track {p.track} is on frame {p.frame}, the video has "
                                f"{len(times)}", "fix the frame in the prompts file")
            out.append(p)
        if not out:
            log.warn(f"{cam.name}: the prompts file has no person for this camera; it gets no tracks")
        return out

    def track_camera(self, cam: CameraInput) -> tuple[MaskTracks, dict]:
        from mamma_kit.video.reader import VideoReader

        rd = VideoReader(cam.video, cam.rotation)
        times = rd.timestamps
        prompts = self.camera_prompts(cam, times)
        builder = MaskTrackBuilder(cam.name, rd.size, times)

        def frames():
            for t, img in rd.frames():
                yield int(np.argmin(np.abs(times - t))), img

        ctx = _inference_context() if self._built else contextlib.nullcontext()
        with ctx, tempfile.TemporaryDirectory(prefix="mamma-sam2-") as tmp:
            stats = run_chunked(self.predictor, frames(), len(times), prompts, self.chunk, builder, Path(tmp))
        raw_ids = sorted({k for _, k in builder.items})
        mt = _keep_ids(builder)
        summ = track_summary(mt)
        summ.update({"chunks": stats.chunks, "max_frames_in_state": stats.max_frames_in_state,
                     "chunk_starts": stats.starts,
                     "prompts": len(prompts), "prompt_ids": raw_ids})
        return mt, summ


def _keep_ids(builder: MaskTrackBuilder) -> MaskTracks:
    """Build keeping the prompt's track ids (users name their people)."""
    mt = builder.build()
    first: dict[int, int] = {}
    for t, k in sorted(builder.items):
        first.setdefault(k, t)
    raw = sorted(first, key=lambda k: (first[k], k))
    mt.track_ids = np.asarray(raw, np.int64)
    return mt


def _inference_context():
    import torch

    return torch.inference_mode()
