"""The shipped BlazePose (and MediaPipe hand) model files and the LiteRT runtime that runs them.

The .tflite files live in ``models/`` beside this file with their SHA-256 sums (SHA256SUMS)
and NOTICE. Nothing is downloaded: a missing or altered file, or a missing runtime, is a UserError.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import sha256_file

MODELS_DIR = Path(__file__).with_name("models")
DETECTOR = "pose_detection.tflite"
LANDMARKER = "pose_landmark_full.tflite"
# MAMMA_KIT_KEYPOINT_MODELS points at another folder holding the same two files (tests use it to
# check that a missing or altered file is refused).
MODELS_ENV = "MAMMA_KIT_KEYPOINT_MODELS"


def models_dir() -> Path:
    return Path(os.environ.get(MODELS_ENV) or MODELS_DIR)


def expected_sums() -> dict[str, str]:
    """File name -> sha256 from the shipped SHA256SUMS (always the package's own list)."""
    sums = {}
    for line in (MODELS_DIR / "SHA256SUMS").read_text().splitlines():
        if line.strip():
            digest, name = line.split()
            sums[name.lstrip("*")] = digest
    return sums


@lru_cache(maxsize=8)
def _verified(path: str, mtime_ns: int, size: int) -> str:
    return sha256_file(path)


def model_path(name: str) -> Path:
    """The checked path of one shipped model file (UserError if missing or altered)."""
    p = models_dir() / name
    reinstall = "reinstall mamma-kit (`pip install -e .` in the repository) to restore the shipped model files"
    if not p.is_file():
        raise UserError(f"keypoint model file missing: {p}", reinstall)
    st = p.stat()
    digest = _verified(str(p), st.st_mtime_ns, st.st_size)
    if digest != expected_sums()[name]:
        raise UserError(f"keypoint model file {p} is altered or corrupt (sha256 {digest[:12]}... differs from "
                        f"the shipped SHA256SUMS)", reinstall)
    return p


class TfliteModel:
    """One .tflite model on LiteRT's CPU interpreter, invoked on batches.

    ``run(x_bhwc)`` -> list of output arrays as the model gives them. The interpreter's input is
    resized when the batch size changes (both BlazePose models accept any batch).
    """

    def __init__(self, name: str, threads: int | None = None):
        try:
            from ai_edge_litert.interpreter import Interpreter
        except ImportError:
            raise UserError("the LiteRT runtime (package ai-edge-litert) is not installed",
                            "install it with `pip install ai-edge-litert`, or reinstall mamma-kit") from None
        path = model_path(name)
        threads = threads or min(2, os.cpu_count() or 1)
        try:
            self.interp = Interpreter(model_path=str(path), num_threads=threads)
        except (ValueError, RuntimeError) as e:
            raise UserError(f"keypoint model {path} cannot be loaded ({e})", "reinstall mamma-kit") from None
        self.name = name
        inp = self.interp.get_input_details()[0]
        self.input_index = int(inp["index"])
        self.input_hw = (int(inp["shape"][1]), int(inp["shape"][2]))
        self.batch = 1
        self.interp.allocate_tensors()
        # outputs in the order of their names (Identity, Identity_1, ...): the models' documented order
        outs = sorted(self.interp.get_output_details(), key=lambda d: (len(d["name"]), d["name"]))
        self.output_index = [int(d["index"]) for d in outs]

    def run(self, x_bhwc: np.ndarray) -> list[np.ndarray]:
        b = int(x_bhwc.shape[0])
        if b != self.batch:
            self.interp.resize_tensor_input(self.input_index, [b, *self.input_hw, 3])
            self.interp.allocate_tensors()
            self.batch = b
        self.interp.set_tensor(self.input_index, np.ascontiguousarray(x_bhwc, np.float32))
        self.interp.invoke()
        # as the model gives them: an output whose graph folds the batch into another axis (the
        # detector's anchors) comes back with a first axis of 1, for the caller to unfold
        return [self.interp.get_tensor(i).copy() for i in self.output_index]
