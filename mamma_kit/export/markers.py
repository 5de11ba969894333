"""Virtual markers: named points on the body surface where a marker-based lab puts its markers
(markers.toml), followed over the fit for gait and musculoskeletal tools (TRC, C3D).

Each marker is one vertex of the body model, chosen once on its rest mesh: a ray from a point
between joints, in a direction of the canonical body (+X left, +Y up, +Z forward), and the
outermost vertex near that ray among those that move with the named joints. Any body in SMPL-X
layout (the open body, SMPL-X) gets the same set by the same rule.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

MARKERS_FILE = Path(__file__).with_name("markers.toml")
RAY_RADIUS_M = 0.015  # vertices this close to the ray are candidates (doubled until one is found)
POSE_BLOCK = 256  # frames posed at a time


@dataclass(frozen=True)
class MarkerSpec:
    name: str
    about: str
    at: dict
    offset: tuple
    toward: tuple | str
    along: tuple | None
    joints: tuple


def _mirrored(spec: MarkerSpec) -> MarkerSpec:
    def side(name: str) -> str:
        return name.replace("left_", "right_")

    flip = np.array([-1.0, 1.0, 1.0])
    toward = side(spec.toward) if isinstance(spec.toward, str) else tuple(np.asarray(spec.toward) * flip)
    return MarkerSpec("R" + spec.name[1:], spec.about.replace("left", "right"), {side(k): w for k, w in spec.at.items()},
                      tuple(np.asarray(spec.offset) * flip), toward,
                      tuple(side(a) for a in spec.along) if spec.along else None, tuple(side(j) for j in spec.joints))


@lru_cache(maxsize=1)
def marker_specs() -> tuple[MarkerSpec, ...]:
    """The marker set of markers.toml, right-side copies after their left ones."""
    out = []
    for name, d in tomllib.loads(MARKERS_FILE.read_text()).items():
        toward = d["toward"] if isinstance(d["toward"], str) else tuple(float(x) for x in d["toward"])
        spec = MarkerSpec(name, d.get("about", ""), dict(d["at"]), tuple(d.get("offset", (0.0, 0.0, 0.0))), toward,
                          tuple(d["along"]) if "along" in d else None, tuple(d["joints"]))
        out.append(spec)
        if d.get("mirror"):
            out.append(_mirrored(spec))
    return tuple(out)


def _vertex_for(spec: MarkerSpec, verts_v3: np.ndarray, joints_j3: np.ndarray, dominant_v: np.ndarray,
                names: list[str]) -> int:
    jid = {n: i for i, n in enumerate(names)}
    origin = sum(w * joints_j3[jid[j]] for j, w in spec.at.items()) + np.asarray(spec.offset)
    d = joints_j3[jid[spec.toward]] - origin if isinstance(spec.toward, str) else np.asarray(spec.toward, float)
    if spec.along:
        axis = joints_j3[jid[spec.along[1]]] - joints_j3[jid[spec.along[0]]]
        axis /= np.linalg.norm(axis)
        d = d - (d @ axis) * axis
    d /= np.linalg.norm(d)
    allowed = np.isin(dominant_v, [jid[j] for j in spec.joints])
    rel = verts_v3 - origin
    s = rel @ d
    perp = np.linalg.norm(rel - s[:, None] * d, axis=1)
    radius = RAY_RADIUS_M
    while True:
        cand = np.flatnonzero(allowed & (s > 0) & (perp < radius))
        if len(cand):
            return int(cand[np.argmax(s[cand])])
        radius *= 2
        if radius > 1.0:
            raise ValueError(f"marker {spec.name}: no vertex of the allowed joints lies along its ray")


@lru_cache(maxsize=8)
def _marker_vertices(sha256: str, model) -> tuple[list[str], np.ndarray]:
    verts = model.np.v_template.astype(np.float64)
    joints = model.np.J_template.astype(np.float64)
    dominant = np.asarray(model.weights_dense.argmax(1))
    specs = marker_specs()
    return [s.name for s in specs], np.array([_vertex_for(s, verts, joints, dominant, model.joint_names)
                                              for s in specs], np.int64)


def marker_vertices(model) -> tuple[list[str], np.ndarray]:
    """The markers' names and (M,) vertex ids on ``model`` (chosen once per model file)."""
    return _marker_vertices(model.sha256, model)


def marker_positions(model, result) -> tuple[list[str], np.ndarray]:
    """Names and (T, M, 3) world positions (Z-up, metres) of the markers over a fitted result."""
    import torch

    from mamma_kit.body.lbs import pose_restricted

    names, ids = marker_vertices(model)
    out = np.zeros((result.num_frames, len(ids), 3))
    with torch.no_grad():
        for a in range(0, result.num_frames, POSE_BLOCK):
            v, _ = pose_restricted(model, result.params(slice(a, a + POSE_BLOCK)), ids)
            out[a:a + POSE_BLOCK] = v.numpy()
    return names, out
