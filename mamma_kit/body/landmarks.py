"""The 512 surface landmarks: weighted farthest-point sampling on the rest mesh.

As in the paper (512 vertices by FPS, more weight on hands, feet and head), each vertex
gets a density weight w (the skinning-mass-weighted mix of its parts' weights below) and
FPS picks, at each step, the vertex maximising w * (distance to the nearest pick), so a
part's spacing shrinks by 1/w and its count grows about as w^2 per unit area.

Deterministic: the start is the vertex maximising w * distance to the centroid, ties go
to the lowest id, and all arithmetic is element-wise float64 numpy (no BLAS reductions).
It takes about 30 ms for a SMPL-X-sized mesh, so no cache is needed; the open body's set
is also baked into its file, which freezes the set the embedded MammaNet was trained on.

Another definition (the official one, issue 11) loads with ``load_landmark_definition``. Both
return a ``LandmarkSet`` (vertex ids and their parts), the set a ``model.BodyModel`` carries.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mamma_kit.body import skeleton as sk
from mamma_kit.core.errors import UserError

LANDMARK_COUNT = 512

#: FPS density weight per part of skeleton.PART_NAMES.
PART_DENSITY = {"left_hand": 3.0, "right_hand": 3.0, "head": 1.8, "left_foot": 1.6, "right_foot": 1.6}


@dataclass
class LandmarkSet:
    """A set of surface landmarks on a model.

    ids: (L,) int64 vertex ids; part: (L,) int64 indices into ``part_names`` (default
    skeleton.LANDMARK_PART_NAMES: body, left_hand, right_hand, head, left_foot, right_foot);
    source: how it was made ("fps", "baked", or a file path).
    """

    ids: np.ndarray
    part: np.ndarray
    part_names: list[str] = field(default_factory=lambda: list(sk.LANDMARK_PART_NAMES))
    source: str = "fps"

    def __len__(self) -> int:
        return len(self.ids)

    def mask(self, part_name: str) -> np.ndarray:
        """(L,) bool: landmarks of one part."""
        return self.part == self.part_names.index(part_name)


def density_weights(weights_vj: np.ndarray) -> np.ndarray:
    """(V,) FPS density of each vertex: parts' PART_DENSITY mixed by skinning mass."""
    part_w = np.array([PART_DENSITY.get(p, 1.0) for p in sk.PART_NAMES])
    joint_w = part_w[sk.JOINT_PART]  # (J,)
    mass = np.maximum(weights_vj.sum(1), 1e-12)
    return (weights_vj * joint_w[None, :]).sum(1) / mass


def weighted_fps(points_v3: np.ndarray, density_v: np.ndarray, count: int) -> np.ndarray:
    """(count,) ids chosen by density-weighted farthest-point sampling (see module doc)."""
    p = np.asarray(points_v3, dtype=np.float64)
    w = np.asarray(density_v, dtype=np.float64)
    if count > len(p):
        raise ValueError(f"cannot pick {count} of {len(p)} points")
    c = p.mean(0)
    d0 = np.sqrt(((p - c) ** 2).sum(1))
    ids = np.empty(count, dtype=np.int64)
    ids[0] = int(np.argmax(w * d0))
    mind = np.full(len(p), np.inf)
    for i in range(1, count):  # one vectorised distance update per pick (count steps, not per vertex)
        q = p[ids[i - 1]]
        mind = np.minimum(mind, np.sqrt(((p - q) ** 2).sum(1)))
        ids[i] = int(np.argmax(w * mind))
    return ids


def landmark_parts_for(vertex_part: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(L,) landmark part labels (skeleton.LANDMARK_PART_NAMES) of vertex ids."""
    return sk.PART_TO_LANDMARK_PART[np.asarray(vertex_part)[ids]].astype(np.int64)


def landmark_set_fps(v_template: np.ndarray, weights_vj: np.ndarray, vertex_part: np.ndarray,
                     count: int = LANDMARK_COUNT):
    """The default landmark set of a model from its rest mesh and skinning weights."""

    ids = weighted_fps(v_template, density_weights(weights_vj), count)
    return LandmarkSet(ids, landmark_parts_for(vertex_part, ids), source="fps")


#: Keys of the official body-part index file -> our landmark parts.
_PART_FILE_KEYS = {"body": "body", "left_hand": "left_hand", "right_hand": "right_hand", "left_feet": "left_foot",
                   "right_feet": "right_foot", "left_head": "head", "right_head": "head"}


def load_landmark_definition(verts_path: str | Path, num_vertices: int, parts_path: str | Path | None = None,
                             vertex_part: np.ndarray | None = None):
    """Read a landmark definition made elsewhere (issue 11's format).

    verts_path: a torch-saved (L, V) tensor (or an .npy/.npz array) whose row argmax is each
        landmark's vertex; V must equal ``num_vertices`` of the model it is used with.
    parts_path: optional .npz with index arrays body, left_hand, right_hand, left_feet,
        right_feet, left_head, right_head (indices into the L landmarks; vertex ids are
        accepted too when they are all among the landmark vertices). Without it the parts
        come from ``vertex_part`` (the model's per-vertex parts).
    Use it with ``model.with_landmarks(load_landmark_definition(p, model.num_vertices, ...,
    vertex_part=model.vertex_part))``.
    """
    from mamma_kit.core.errors import require_file

    vp = require_file(verts_path, "landmark definition")
    if vp.suffix in (".npy", ".npz"):
        try:
            with np.load(vp, allow_pickle=False) as z:
                arr = z[z.files[0]] if hasattr(z, "files") else z
                arr = np.asarray(arr)
        except AttributeError:
            arr = np.load(vp, allow_pickle=False)
        except ValueError as e:
            raise UserError(f"landmark definition {vp} is unreadable ({e})", "save it as a plain array") from None
    else:
        import torch

        try:
            obj = torch.load(vp, map_location="cpu", weights_only=True)
        except Exception as e:  # noqa: BLE001 - any failure means the file is not a plain tensor
            raise UserError(f"landmark definition {vp} is not a plain torch tensor file ({type(e).__name__})",
                            "save it with torch.save(tensor) (weights_only loading refuses pickled objects)") from None
        if isinstance(obj, dict) and len(obj) == 1:
            obj = next(iter(obj.values()))
        if not isinstance(obj, torch.Tensor):
            raise UserError(f"landmark definition {vp} holds a {type(obj).__name__}, not a tensor",
                            "save the (L, V) tensor itself")
        arr = obj.float().numpy()
    if arr.ndim != 2:
        raise UserError(f"landmark definition {vp} has shape {arr.shape}, expected (L, V)", "check the file")
    if arr.shape[1] != num_vertices:
        raise UserError(f"landmark definition {vp} is for a {arr.shape[1]}-vertex body, the body model has "
                        f"{num_vertices} vertices", "use the body model it was made for (--body-model)")
    ids = np.argmax(arr, axis=1).astype(np.int64)
    if parts_path is None:
        if vertex_part is None:
            raise ValueError("need parts_path or vertex_part")
        return LandmarkSet(ids, landmark_parts_for(vertex_part, ids), source=str(vp))
    pp = require_file(parts_path, "landmark part file")
    try:
        with np.load(pp, allow_pickle=False) as z:
            groups = {k: np.asarray(z[k]).astype(np.int64).ravel() for k in z.files}
    except ValueError as e:
        raise UserError(f"landmark part file {pp} is unreadable ({e})", "save plain index arrays with np.savez") from None
    unknown = set(groups) - set(_PART_FILE_KEYS)
    if unknown:
        raise UserError(f"landmark part file {pp} has unknown keys {sorted(unknown)}",
                        f"expected {sorted(_PART_FILE_KEYS)}")
    part = np.full(len(ids), -1, dtype=np.int64)
    for k, idx in groups.items():
        if len(idx) and idx.max() >= len(ids):  # vertex ids rather than landmark indices
            pos = {int(v): i for i, v in enumerate(ids)}
            if not all(int(v) in pos for v in idx):
                raise UserError(f"landmark part file {pp}: '{k}' holds ids that are neither landmark indices "
                                "nor landmark vertices", "check that it belongs to this definition")
            idx = np.array([pos[int(v)] for v in idx], dtype=np.int64)
        part[idx] = sk.LANDMARK_PART_NAMES.index(_PART_FILE_KEYS[k])
    if (part < 0).any():
        raise UserError(f"landmark part file {pp} leaves {int((part < 0).sum())} landmarks without a part",
                        "every landmark needs one of its groups")
    return LandmarkSet(ids, part, source=str(vp))
