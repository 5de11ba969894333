"""Per-person SMPL-X result files: ``smplx/person_<k>.npz`` (DESIGN.md section 3).

Keys (T frames; all float64 except where noted):

    betas (16,)            per person            global_orient (T, 3)
    body_pose (T, 63)      left_hand_pose (T, 45) right_hand_pose (T, 45)
    jaw_pose (T, 3)        leye_pose (T, 3)       reye_pose (T, 3)
    expression (T, 10)     transl (T, 3)          joints (T, 55, 3) posed joints, metres
    frame_times (T,)       reference-clock seconds of each frame
    fps ()                 nominal frame rate
    body_model (2,) str    [name, sha256 of the model file]
    gender () str          producer () str: JSON (tool, version, command, input hashes)

Axis-angle rotations in SMPL-X's convention (hands absolute: zero = flat hand, i.e.
smplx's flat_hand_mean=True). Poses are in mamma-kit's world frame (Z up): global_orient and
transl place the canonical (Y up) body there. Reading validates every key and shape and
raises UserError with what is wrong.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_npz, write_npz

NUM_BETAS = 16
POSE_KEYS = {"global_orient": 3, "body_pose": 63, "left_hand_pose": 45, "right_hand_pose": 45,
             "jaw_pose": 3, "leye_pose": 3, "reye_pose": 3, "expression": 10, "transl": 3}
ALL_KEYS = ("betas", *POSE_KEYS, "joints", "frame_times", "fps", "body_model", "gender", "producer")


@dataclass
class SmplxResult:
    """One person's SMPL-X parameters over T frames (shapes in the module docstring)."""

    betas: np.ndarray
    global_orient: np.ndarray
    body_pose: np.ndarray
    left_hand_pose: np.ndarray
    right_hand_pose: np.ndarray
    jaw_pose: np.ndarray
    leye_pose: np.ndarray
    reye_pose: np.ndarray
    expression: np.ndarray
    transl: np.ndarray
    joints: np.ndarray
    frame_times: np.ndarray
    fps: float
    body_model_name: str
    body_model_sha256: str
    gender: str = "neutral"
    producer: dict = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        return int(self.transl.shape[0])

    def take(self, frames: np.ndarray) -> "SmplxResult":
        """The result on the frames ``frames`` (indices, in order)."""
        from dataclasses import replace

        per_frame = {k: getattr(self, k)[frames] for k in (*POSE_KEYS, "joints", "frame_times")}
        return replace(self, **per_frame)

    def params(self, frames: slice | np.ndarray | int | None = None) -> dict[str, np.ndarray]:
        """LBS parameter dict (body.lbs): per-frame arrays (T', n) and betas (16,) broadcast.
        ``frames`` selects frames (an int keeps a leading dim of 1)."""
        sel = slice(None) if frames is None else ([frames] if isinstance(frames, (int, np.integer)) else frames)
        out = {k: getattr(self, k)[sel] for k in POSE_KEYS}
        out["betas"] = self.betas
        return out

    @classmethod
    def from_params(cls, params: dict, joints: np.ndarray, frame_times: np.ndarray, fps: float,
                    body_model_name: str, body_model_sha256: str, gender: str = "neutral",
                    producer: dict | None = None) -> "SmplxResult":
        """Build from an LBS parameter dict (missing pose keys become zeros, torch tensors ok)."""
        T = int(np.asarray(joints).shape[0])

        def arr(k, n):
            v = params.get(k)
            if v is None:
                return np.zeros((T, n))
            v = v.detach().cpu().numpy() if hasattr(v, "detach") else np.asarray(v)
            return np.broadcast_to(np.asarray(v, dtype=np.float64), (T, n)).copy()

        b = params.get("betas")
        b = np.zeros(NUM_BETAS) if b is None else (b.detach().cpu().numpy() if hasattr(b, "detach") else np.asarray(b))
        return cls(betas=np.asarray(b, dtype=np.float64).reshape(-1)[:NUM_BETAS],
                   **{k: arr(k, n) for k, n in POSE_KEYS.items()},
                   joints=np.asarray(joints, dtype=np.float64), frame_times=np.asarray(frame_times, dtype=np.float64),
                   fps=float(fps), body_model_name=body_model_name, body_model_sha256=body_model_sha256,
                   gender=gender, producer=producer or {})


def write_smplx_result(path: str | Path, r: SmplxResult) -> Path:
    """Validate and atomically write one person's result (.npz, compressed)."""
    arrays = {"betas": np.asarray(r.betas, np.float64)}
    arrays.update({k: np.asarray(getattr(r, k), np.float64) for k in POSE_KEYS})
    arrays.update(joints=np.asarray(r.joints, np.float64), frame_times=np.asarray(r.frame_times, np.float64),
                  fps=np.float64(r.fps), body_model=np.array([r.body_model_name, r.body_model_sha256]),
                  gender=np.array(r.gender), producer=np.array(json.dumps(r.producer, sort_keys=True)))
    _validate(arrays, Path(path))
    return write_npz(path, **arrays)


def _validate(d: dict, path: Path) -> None:
    def bad(msg):
        return UserError(f"SMPL-X result {path}: {msg}", "regenerate it with `mamma-kit fit`")

    missing = [k for k in ALL_KEYS if k not in d]
    if missing:
        raise bad(f"missing keys {missing}")
    if d["betas"].shape != (NUM_BETAS,):
        raise bad(f"betas has shape {d['betas'].shape}, expected ({NUM_BETAS},)")
    T = d["transl"].shape[0] if d["transl"].ndim == 2 else -1
    for k, n in POSE_KEYS.items():
        if d[k].shape != (T, n):
            raise bad(f"{k} has shape {d[k].shape}, expected ({T}, {n})")
    if d["joints"].shape != (T, 55, 3):
        raise bad(f"joints has shape {d['joints'].shape}, expected ({T}, 55, 3)")
    if d["frame_times"].shape != (T,):
        raise bad(f"frame_times has shape {d['frame_times'].shape}, expected ({T},)")
    if T > 1 and np.any(np.diff(d["frame_times"]) <= 0):
        raise bad("frame_times are not strictly increasing")
    for k in ("betas", *POSE_KEYS, "joints", "frame_times"):
        if not np.issubdtype(d[k].dtype, np.number) or not np.all(np.isfinite(d[k])):
            raise bad(f"{k} holds NaN, inf or non-numbers")
    if np.asarray(d["fps"]).shape != () or not float(d["fps"]) > 0:
        raise bad("fps must be one positive number")
    if np.asarray(d["body_model"]).shape != (2,) or d["body_model"].dtype.kind != "U":
        raise bad("body_model must be [name, sha256] strings")
    if d["gender"].dtype.kind != "U" or d["producer"].dtype.kind != "U":
        raise bad("gender and producer must be strings")


def read_smplx_result(path: str | Path) -> SmplxResult:
    """Read and validate one person's result file (UserError on anything malformed)."""
    p = Path(path)
    d = read_npz(p, "SMPL-X result")
    _validate(d, p)
    try:
        producer = json.loads(str(d["producer"]))
    except json.JSONDecodeError:
        raise UserError(f"SMPL-X result {p}: producer is not valid JSON", "regenerate it") from None
    return SmplxResult(betas=d["betas"], **{k: d[k] for k in POSE_KEYS}, joints=d["joints"],
                       frame_times=d["frame_times"], fps=float(d["fps"]), body_model_name=str(d["body_model"][0]),
                       body_model_sha256=str(d["body_model"][1]), gender=str(d["gender"]), producer=producer)
