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
"""

from mamma_kit.body.lbs import UPRIGHT_ORIENT, pose_mesh, pose_mesh_np, pose_restricted
from mamma_kit.body.model import BodyModel, LandmarkSet, load_body_model
from mamma_kit.body.proxy import ProxyMesh, pose_proxy, signed_distance

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["kp_regressor", "landmarks", "lbs", "model", "proxy", "skeleton"]
