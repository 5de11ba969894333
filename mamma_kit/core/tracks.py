"""Per-view person tracks: masks/<cam>.npz, keypoints/<cam>.npz and landmarks/<cam>.npz.

Both files index frames by the camera's own frame timestamps (``frame_times``, float64 s,
container time) and people by per-view ``track_ids`` (K,). Ground truth in synthetic
workspaces uses the same files under gt/, with track id = person id.

masks/<cam>.npz
    image_size (2,) [W, H]; frame_times (T,); track_ids (K,);
    boxes (T, K, 4) float32 x1, y1, x2, y2 (NaN where the track is absent);
    scores (T, K) float32 (0 where absent);
    rle_counts (N,) uint32 and rle_index (T, K, 2) int64 [start, length] into rle_counts:
    the mask flattened row-major, as alternating run lengths starting with a run of 0s
    (length 0 = no mask).

In memory, landmarks and keypoints are frames x tracks arrays (of a take, or of a window of one);
on disk they are rows, one per (frame, track) a stage looked at (core/trackrows.py: row_frame and
row_track (N,), each array below with N rows in place of (T, K)), so a file grows with the
person-frames there are, not with frames x tracks.

landmarks/<cam>.npz  (L = 512)
    image_size, frame_times, track_ids as above; valid (T, K) bool;
    xy (T, K, L, 2) px; sigma (T, K, L, 2) px per axis; visibility, contact,
    floor_contact (T, K, L) probabilities in [0, 1]; landmark_set (str); source (str).

keypoints/<cam>.npz  (P = 33 BlazePose points, in the model's order: keypoints.blazepose.POINT_NAMES)
    image_size, frame_times, track_ids as above; valid (T, K) bool; xy (T, K, P, 2) px;
    z (T, K, P) depth relative to the hips (px-scaled, smaller = nearer); visibility, presence
    (T, K, P) in [0, 1]; score (T, K) the model's pose flag (0 where invalid); model (str);
    hand_xy (T, K, 2, 21, 2) px of each person's left and right hand (MediaPipe's 21 hand points,
    NaN where not read), hand_presence (T, K, 2) the hand model's flag (0 where not read) and
    hand_right (T, K, 2) its handedness score (1: a right hand; NaN where not read).

Every file also holds ``producer`` (JSON string: tool, version, command, input hashes).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_npz, write_npz

N_HAND_POINTS = 21  # MediaPipe's hand landmarks per hand (keypoints/hands.py)
HAND_SURE_FLAG = 0.5  # the hand model's flag above which it saw a hand in its ROI


def nearest_frames(times_a: np.ndarray, times_b: np.ndarray, tol: float | None = None) -> np.ndarray:
    """For each time in a, the index of the nearest time in b (-1 if farther than tol; default half a frame)."""
    a, b = np.asarray(times_a, np.float64), np.asarray(times_b, np.float64)
    if len(b) == 0:
        return np.full(len(a), -1, np.int64)
    if tol is None:
        tol = 0.5 * float(np.median(np.diff(b))) if len(b) > 1 else 1e-3
    i = np.clip(np.searchsorted(b, a), 1, max(len(b) - 1, 1)) if len(b) > 1 else np.zeros(len(a), np.int64)
    if len(b) > 1:
        i = np.where(np.abs(b[i - 1] - a) <= np.abs(b[i] - a), i - 1, i)
    return np.where(np.abs(b[i] - a) <= tol + 1e-9, i, -1).astype(np.int64)


def track_colour(track_id: int) -> tuple[int, int, int]:
    """A distinct, stable RGB colour per id (golden-ratio hue steps), for every stage's pictures."""
    import cv2

    hue = int((track_id * 0.61803398875 % 1.0) * 179)
    hsv = np.uint8([[[hue, 200, 255]]])
    return tuple(int(v) for v in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])


# ---- run-length encoding ---------------------------------------------------------------
def rle_encode(mask_hw: np.ndarray) -> np.ndarray:
    """Boolean mask (H, W) -> run lengths (uint32) of the row-major flattening, 0-run first."""
    flat = np.asarray(mask_hw, bool).reshape(-1)
    if flat.size == 0:
        return np.zeros(0, np.uint32)
    change = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.r_[0, change, flat.size]
    runs = np.diff(bounds)
    if flat[0]:
        runs = np.r_[0, runs]
    return runs.astype(np.uint32)


def rle_decode(counts: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    """Run lengths -> boolean mask (H, W)."""
    w, h = int(size_wh[0]), int(size_wh[1])
    counts = np.asarray(counts, np.int64)
    if counts.sum() != w * h:
        raise ValueError(f"RLE covers {counts.sum()} pixels, image has {w * h}")
    values = np.zeros(len(counts), bool)
    values[1::2] = True
    return np.repeat(values, counts).reshape(h, w)


def encode_mask(mask_hw: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """A mask as it is kept in a track file: its runs (rle_encode) and box x1, y1, x2, y2 (4,); None if empty."""
    m = np.asarray(mask_hw, bool)
    if not m.any():
        return None
    ys, xs = np.nonzero(m.any(1))[0], np.nonzero(m.any(0))[0]
    return rle_encode(m), np.array([xs[0], ys[0], xs[-1] + 1, ys[-1] + 1], np.float32)


def rle_area(counts: np.ndarray) -> int:
    return int(np.asarray(counts, np.int64)[1::2].sum())


def _producer_str(producer: dict | None) -> np.ndarray:
    return np.array(json.dumps(producer or {}))


# ---- masks ------------------------------------------------------------------------------
@dataclass
class MaskTracks:
    camera: str
    image_size: tuple[int, int]
    frame_times: np.ndarray  # (T,) float64
    track_ids: np.ndarray  # (K,) int64
    boxes: np.ndarray  # (T, K, 4) float32
    scores: np.ndarray  # (T, K) float32
    rle_counts: np.ndarray  # (N,) uint32
    rle_index: np.ndarray  # (T, K, 2) int64
    producer: dict = field(default_factory=dict)

    @property
    def present(self) -> np.ndarray:
        """(T, K) bool: the track has a mask in that frame."""
        return self.rle_index[..., 1] > 0

    def track_column(self, track_id: int) -> int:
        hits = np.flatnonzero(self.track_ids == track_id)
        if not len(hits):
            raise KeyError(f"track {track_id} not in {self.camera}")
        return int(hits[0])

    def mask(self, t: int, k: int) -> np.ndarray | None:
        """Boolean mask (H, W) of column k at frame t, or None if absent."""
        start, n = self.rle_index[t, k]
        if n == 0:
            return None
        return rle_decode(self.rle_counts[start:start + n], self.image_size)

    def area(self, t: int, k: int) -> int:
        start, n = self.rle_index[t, k]
        return rle_area(self.rle_counts[start:start + n]) if n else 0

    @classmethod
    def from_masks(cls, camera: str, image_size: tuple[int, int], frame_times: np.ndarray,
                   track_ids: np.ndarray, masks: dict[tuple[int, int], np.ndarray | tuple],
                   scores: dict[tuple[int, int], float] | None = None, producer: dict | None = None) -> "MaskTracks":
        """Build from {(frame index, column): bool mask (H, W), or encode_mask's (runs, box)}; boxes
        come from the masks."""
        T, K = len(frame_times), len(track_ids)
        boxes = np.full((T, K, 4), np.nan, np.float32)
        sc = np.zeros((T, K), np.float32)
        index = np.zeros((T, K, 2), np.int64)
        chunks, n = [], 0
        for (t, k) in sorted(masks):
            m = masks[(t, k)]
            enc = m if isinstance(m, tuple) or m is None else encode_mask(m)
            if enc is None:
                continue
            counts, boxes[t, k] = enc
            index[t, k] = (n, len(counts))
            chunks.append(counts)
            n += len(counts)
            sc[t, k] = 1.0 if scores is None else scores.get((t, k), 1.0)
        counts_all = np.concatenate(chunks).astype(np.uint32) if chunks else np.zeros(0, np.uint32)
        return cls(camera, (int(image_size[0]), int(image_size[1])), np.asarray(frame_times, np.float64),
                   np.asarray(track_ids, np.int64), boxes, sc, counts_all, index, producer or {})

    def save(self, path: str | Path) -> Path:
        return write_npz(path, camera=np.array(self.camera), image_size=np.asarray(self.image_size, np.int64),
                         frame_times=self.frame_times, track_ids=self.track_ids, boxes=self.boxes,
                         scores=self.scores, rle_counts=self.rle_counts, rle_index=self.rle_index,
                         producer=_producer_str(self.producer))

    @classmethod
    def load(cls, path: str | Path) -> "MaskTracks":
        d = read_npz(path, "mask file")
        _require(d, path, ("image_size", "frame_times", "track_ids", "boxes", "scores", "rle_counts", "rle_index"))
        return cls(str(d.get("camera", Path(path).stem)), tuple(int(v) for v in d["image_size"]),
                   d["frame_times"], d["track_ids"], d["boxes"], d["scores"], d["rle_counts"], d["rle_index"],
                   json.loads(str(d.get("producer", "{}"))))


def track_frame_count(path: str | Path) -> int:
    """Frames of a track file (masks, keypoints, landmarks) without reading its other arrays."""
    d = read_npz(path, "track file", keys=("frame_times",))
    _require(d, path, ("frame_times",))
    return len(d["frame_times"])


# ---- landmarks --------------------------------------------------------------------------
@dataclass
class LandmarkTracks:
    camera: str
    image_size: tuple[int, int]
    frame_times: np.ndarray  # (T,)
    track_ids: np.ndarray  # (K,)
    valid: np.ndarray  # (T, K) bool
    xy: np.ndarray  # (T, K, L, 2) px
    sigma: np.ndarray  # (T, K, L, 2) px
    visibility: np.ndarray  # (T, K, L)
    contact: np.ndarray  # (T, K, L)
    floor_contact: np.ndarray  # (T, K, L)
    landmark_set: str = ""
    source: str = ""
    producer: dict = field(default_factory=dict)

    @staticmethod
    def cell_spec(n: int) -> dict:
        """Each per-cell array: (shape after (T, K), dtype, an empty cell's value); n landmarks."""
        return {"valid": ((), bool, False), "xy": ((n, 2), np.float32, np.nan), "sigma": ((n, 2), np.float32, np.nan),
                "visibility": ((n,), np.float32, 0.0), "contact": ((n,), np.float32, 0.0),
                "floor_contact": ((n,), np.float32, 0.0)}

    @property
    def n_landmarks(self) -> int:
        return self.xy.shape[2]

    n_points = n_landmarks

    @classmethod
    def empty(cls, camera: str, image_size, frame_times, track_ids, n_landmarks: int = 512,
              landmark_set: str = "", source: str = "") -> "LandmarkTracks":
        from mamma_kit.core.trackrows import empty_cells

        cells = empty_cells(cls.cell_spec(n_landmarks), len(frame_times), len(track_ids))
        return cls(camera, (int(image_size[0]), int(image_size[1])), np.asarray(frame_times, np.float64),
                   np.asarray(track_ids, np.int64), landmark_set=landmark_set, source=source, **cells)

    def save(self, path: str | Path) -> Path:
        """landmarks/<cam>.npz as rows (core/trackrows.py): the cells that hold a detection."""
        from mamma_kit.core.trackrows import save_rows

        return save_rows(self, path)

    @classmethod
    def load(cls, path: str | Path) -> "LandmarkTracks":
        """A whole landmark file (core/trackrows.TrackFile reads a window of frames)."""
        from mamma_kit.core.trackrows import load_tracks

        return load_tracks(cls, path, "landmark file")


# ---- keypoints --------------------------------------------------------------------------
@dataclass
class KeypointTracks:
    camera: str
    image_size: tuple[int, int]
    frame_times: np.ndarray  # (T,)
    track_ids: np.ndarray  # (K,)
    valid: np.ndarray  # (T, K) bool
    xy: np.ndarray  # (T, K, P, 2) px
    z: np.ndarray  # (T, K, P)
    visibility: np.ndarray  # (T, K, P)
    presence: np.ndarray  # (T, K, P)
    score: np.ndarray  # (T, K)
    model: str = ""
    producer: dict = field(default_factory=dict)
    # each person's hands (0 left, 1 right; MediaPipe's 21 points, keypoints/hands.py): px, NaN where
    # not read, and the hand model's flag (0 where not read). Files from before hands load as unread.
    hand_xy: np.ndarray | None = None  # (T, K, 2, 21, 2)
    hand_presence: np.ndarray | None = None  # (T, K, 2)
    hand_right: np.ndarray | None = None  # (T, K, 2) the hand model's handedness (1: a right hand; NaN: not read)

    @staticmethod
    def cell_spec(n: int) -> dict:
        """Each per-cell array: (shape after (T, K), dtype, an empty cell's value); n body points."""
        return {"valid": ((), bool, False), "xy": ((n, 2), np.float32, np.nan), "z": ((n,), np.float32, np.nan),
                "visibility": ((n,), np.float32, 0.0), "presence": ((n,), np.float32, 0.0),
                "score": ((), np.float32, 0.0), "hand_xy": ((2, N_HAND_POINTS, 2), np.float32, np.nan),
                "hand_presence": ((2,), np.float32, 0.0), "hand_right": ((2,), np.float32, np.nan)}

    @property
    def n_points(self) -> int:
        return self.xy.shape[2]

    def __post_init__(self):
        T, K = self.valid.shape
        for name in ("hand_xy", "hand_presence", "hand_right"):
            if getattr(self, name) is None:
                shape, dtype, fill = self.cell_spec(1)[name]
                setattr(self, name, np.full((T, K, *shape), fill, dtype))

    @classmethod
    def empty(cls, camera: str, image_size, frame_times, track_ids, n_points: int = 33,
              model: str = "") -> "KeypointTracks":
        from mamma_kit.core.trackrows import empty_cells

        cells = empty_cells(cls.cell_spec(n_points), len(frame_times), len(track_ids))
        return cls(camera, (int(image_size[0]), int(image_size[1])), np.asarray(frame_times, np.float64),
                   np.asarray(track_ids, np.int64), model=model, **cells)

    def save(self, path: str | Path) -> Path:
        """keypoints/<cam>.npz as rows (core/trackrows.py): the cells the model looked at."""
        from mamma_kit.core.trackrows import save_rows

        return save_rows(self, path)

    @classmethod
    def load(cls, path: str | Path) -> "KeypointTracks":
        """A whole keypoint file (core/trackrows.TrackFile reads a window of frames)."""
        from mamma_kit.core.trackrows import load_tracks

        return load_tracks(cls, path, "keypoint file")


def _require(d: dict, path, keys) -> None:
    missing = [k for k in keys if k not in d]
    if missing:
        raise UserError(f"{Path(path).name} is missing {', '.join(missing)} (not a mamma-kit file or too old)",
                        "run the stage that writes it again")


def join_frame_ranges(parts: list[tuple[int, int, object]]):
    """One camera's tracks from parts computed on frame ranges: [(start, stop, tracks)], every
    part a KeypointTracks or LandmarkTracks of the whole camera (same frames and tracks) that
    holds results only in its rows start:stop. Returns the first part with the others' rows."""
    _, _, out = parts[0]
    T = len(out.frame_times)
    for start, stop, part in parts[1:]:
        if len(part.frame_times) != T or not np.array_equal(part.track_ids, out.track_ids):
            raise ValueError("frame-range parts of one camera must share its frames and tracks")
        for f in fields(out):
            a = getattr(out, f.name)
            if isinstance(a, np.ndarray) and a.ndim >= 2 and a.shape[0] == T:
                a[start:stop] = getattr(part, f.name)[start:stop]
    return out


def append_tracks(base, extra):
    """``base``'s tracks followed by ``extra``'s: one MaskTracks, KeypointTracks or LandmarkTracks of
    the same camera and frames. Every (T, K, ...) array is joined along K; a MaskTracks' RLE runs are
    appended and its index moved past ``base``'s."""
    if type(base) is not type(extra) or not np.array_equal(base.frame_times, extra.frame_times):
        raise ValueError("append_tracks: not the same kind of tracks on the same frames")
    T, K = len(base.frame_times), len(base.track_ids)
    changes = {"track_ids": np.r_[base.track_ids, extra.track_ids].astype(np.int64)}
    for f in fields(base):
        a = getattr(base, f.name)
        if f.name == "frame_times" or not isinstance(a, np.ndarray) or a.ndim < 2 or a.shape[:2] != (T, K):
            continue
        b = getattr(extra, f.name)
        if f.name == "rle_index":
            b = b + np.array([len(base.rle_counts), 0], np.int64)
        changes[f.name] = np.concatenate([a, b.astype(a.dtype, copy=False)], 1)
    if isinstance(base, MaskTracks):
        changes["rle_counts"] = np.r_[base.rle_counts, extra.rle_counts].astype(base.rle_counts.dtype)
    return replace(base, **changes)
