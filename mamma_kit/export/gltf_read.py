"""Read a glTF file back as a viewer plays it: every node's world matrix at a time, from its node
tree and its animations (linear, normalised-quaternion and step sampling, clamped at the ends).
What checks an export (tests/test_export.py, benchmarks/export_check.py) evaluates."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as g
from scipy.spatial.transform import Rotation

_DTYPES = {g.FLOAT: np.float32, g.UNSIGNED_SHORT: np.uint16, g.UNSIGNED_INT: np.uint32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_PATHS = {"translation": 0, "rotation": 1, "scale": 2}


class GltfScene:
    """A loaded .glb / .gltf: ``array(i)`` reads accessor i, ``world(t)`` every node's 4x4 at time t."""

    def __init__(self, path: str | Path):
        self.gltf = g.GLTF2().load(str(path))
        self.blob = self.gltf.binary_blob()
        self.node_id = {n.name: i for i, n in enumerate(self.gltf.nodes)}
        self._channels = [(ch.target.node, _PATHS[ch.target.path], self.array(s.input).astype(float),
                           self.array(s.output).astype(float), s.interpolation == g.ANIM_STEP)
                          for a in self.gltf.animations for ch in a.channels for s in [a.samplers[ch.sampler]]]

    def array(self, i: int) -> np.ndarray:
        acc = self.gltf.accessors[i]
        view = self.gltf.bufferViews[acc.bufferView]
        w = _WIDTH[acc.type]
        a = np.frombuffer(self.blob, _DTYPES[acc.componentType], acc.count * w, view.byteOffset + (acc.byteOffset or 0))
        return a.reshape(acc.count, w) if w > 1 else a

    @staticmethod
    def _sample(times: np.ndarray, values: np.ndarray, t: float, step: bool) -> np.ndarray:
        i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1))
        if step or i == len(times) - 1 or t <= times[0]:
            return values[i]
        a = (t - times[i]) / (times[i + 1] - times[i])
        v = (1 - a) * values[i] + a * values[i + 1]
        return v / np.linalg.norm(v) if len(v) == 4 else v

    def world(self, t: float) -> dict[int, np.ndarray]:
        """Node id -> world matrix (4, 4) at animation time t (seconds)."""
        trs = {i: [np.array(n.translation or [0, 0, 0], float), np.array(n.rotation or [0, 0, 0, 1], float),
                   np.array(n.scale or [1, 1, 1], float)] for i, n in enumerate(self.gltf.nodes)}
        for node, path, times, values, step in self._channels:
            trs[node][path] = self._sample(times, values, t, step)
        out: dict[int, np.ndarray] = {}
        stack = [(i, np.eye(4)) for i in self.gltf.scenes[self.gltf.scene or 0].nodes]
        while stack:
            i, parent = stack.pop()
            tr, q, sc = trs[i]
            M = np.eye(4)
            M[:3, :3] = Rotation.from_quat(q).as_matrix() * sc
            M[:3, 3] = tr
            out[i] = parent @ M
            stack += [(c, out[i]) for c in self.gltf.nodes[i].children or []]
        return out
