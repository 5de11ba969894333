"""Body models in SMPL-X layout: loading (open body or SMPL-X .npz), LBS, landmarks, proxy.

Public interface (see each module's docstring):

- ``load_body_model(spec="open", gender="neutral") -> BodyModel``
- ``pose_restricted(model, params, vertex_ids=None) -> (verts, joints)``: landmarks (default)
  or any vertex subset + 55 joints, differentiable; ``pose_mesh`` (all vertices, torch) and
  ``pose_mesh_np`` (numpy, no grad, chunked) for export, rendering and synthesis.
- ``model.landmark_ids`` (512,), ``model.landmark_parts`` (512,) into
  ``skeleton.LANDMARK_PART_NAMES``; ``model.vertex_parts`` (V,) into ``skeleton.PART_NAMES``.
- ``model.proxy`` (ProxyMesh), ``pose_proxy(model, params)``, ``signed_distance(points, verts,
  faces)`` (negative inside).
- ``UPRIGHT_ORIENT``: global_orient that stands the canonical Y-up body up in the Z-up world.

These names are imported lazily, so ``import mamma_kit.body.skeleton`` does not load torch.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "UPRIGHT_ORIENT": "lbs", "pose_mesh": "lbs", "pose_mesh_np": "lbs", "pose_restricted": "lbs",
    "BodyModel": "model", "load_body_model": "model", "LandmarkSet": "landmarks",
    "ProxyMesh": "proxy", "pose_proxy": "proxy", "signed_distance": "proxy",
}

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["kp_regressor", "landmarks", "lbs", "model", "proxy", "rest_pose", "skeleton"]


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"mamma_kit.body.{_EXPORTS[name]}"), name)
    raise AttributeError(name)
