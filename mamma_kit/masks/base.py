"""The interface every mask backend implements, and what they share.

A backend turns one camera's video into a core.tracks.MaskTracks: per frame (the video's own
timestamps) and track, a mask (RLE), its box and a score, with track ids that stay with one
person for as long as the backend can follow them. ``backends.get_backend(name, **options)``
builds one (the backends import this module, so it imports none of them).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from mamma_kit.core.tracks import MaskTracks


@dataclass
class CameraInput:
    """What a backend gets for one camera."""

    name: str
    video: Path
    workspace_root: Path
    # the camera's board video: calibration assumes the camera did not move between it and
    # the capture, so the builtin backend can take an empty-scene background from it
    board_video: Path | None = None
    rotation: int | None = None  # capture.toml's override of the files' display rotation (None: theirs)


class MaskBackend(Protocol):
    name: str

    def track_camera(self, cam: CameraInput) -> tuple[MaskTracks, dict]:
        """-> (tracks, summary dict for --json)."""
        ...


def track_summary(mt: MaskTracks) -> dict:
    present = mt.present
    return {"camera": mt.camera, "frames": int(len(mt.frame_times)), "tracks": int(len(mt.track_ids)),
            "instances": int(present.sum()),
            "frames_per_track": {str(int(t)): int(n) for t, n in zip(mt.track_ids, present.sum(0))}}


class MaskTrackBuilder:
    """Collects masks frame by frame as RLE (memory stays bounded by the compressed masks)."""

    def __init__(self, camera: str, image_size: tuple[int, int], frame_times: np.ndarray):
        self.camera, self.image_size = camera, (int(image_size[0]), int(image_size[1]))
        self.frame_times = np.asarray(frame_times, np.float64)
        self.items: dict[tuple[int, int], tuple[np.ndarray, tuple, float]] = {}  # (t, raw id) -> rle, box, score

    def add(self, t: int, track: int, mask_hw: np.ndarray, score: float = 1.0) -> None:
        from mamma_kit.core.tracks import rle_encode

        if mask_hw is None or not mask_hw.any():
            return
        ys, xs = np.nonzero(mask_hw.any(1))[0], np.nonzero(mask_hw.any(0))[0]
        self.items[(int(t), int(track))] = (rle_encode(mask_hw), (xs[0], ys[0], xs[-1] + 1, ys[-1] + 1), float(score))

    def build(self, producer: dict | None = None) -> MaskTracks:
        """Track ids become 0..K-1 in order of first appearance."""
        first: dict[int, int] = {}
        for t, k in sorted(self.items):
            first.setdefault(k, t)
        raw = sorted(first, key=lambda k: (first[k], k))
        col = {k: i for i, k in enumerate(raw)}
        T, K = len(self.frame_times), len(raw)
        boxes = np.full((T, K, 4), np.nan, np.float32)
        sc = np.zeros((T, K), np.float32)
        index = np.zeros((T, K, 2), np.int64)
        chunks, n = [], 0
        for (t, k), (counts, box, score) in sorted(self.items.items()):
            c = col[k]
            index[t, c] = (n, len(counts))
            boxes[t, c] = box
            sc[t, c] = score
            chunks.append(counts)
            n += len(counts)
        counts_all = np.concatenate(chunks).astype(np.uint32) if chunks else np.zeros(0, np.uint32)
        return MaskTracks(self.camera, self.image_size, self.frame_times, np.arange(K, dtype=np.int64), boxes, sc,
                          counts_all, index, producer or {})
