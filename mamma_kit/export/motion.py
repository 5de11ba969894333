"""A fitted person as a skeleton in motion: local joint rotations and offsets, what every
animation format (glTF, BVH) stores, computed once from a result file and its body model.

The body's rest joints come from its shape (``J_template + J_shapedirs . betas``, plus the
expression's effect where the model has one); each joint's local rotation is its axis-angle
parameter. The root's local transform holds global_orient and its posed position
(rest pelvis + transl), so the root sits in mamma-kit's Z-up world; ``Z_UP_TO_Y_UP`` turns that
world into the Y-up frame glTF, BVH and OpenSim expect.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mamma_kit.body import skeleton as sk

#: (x, y, z) in the Z-up world -> (x, z, -y): Y up, the world's -Y towards the viewer (+Z).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass
class SkeletonMotion:
    """One person's skeleton over T frames (J = 55 SMPL-X joints, float64, metres, seconds).

    times_t: (T,) reference-clock seconds of the fitted frames.
    rot_tj33: (T, J, 3, 3) local rotations; the root's turns the canonical Y-up body into the world.
    offset_tj3: (T, J, 3) local translations: the root's is its world position (Z-up), a child's
        its rest offset from its parent (the same every frame unless an expression moves the joints).
    rest_j3: (J, 3) the first frame's rest joints (canonical frame): the bind pose of a skinned mesh.
    fps: the nominal frame rate of the fit.
    """

    names: list[str]
    parents: np.ndarray
    times_t: np.ndarray
    rot_tj33: np.ndarray
    offset_tj3: np.ndarray
    rest_j3: np.ndarray
    fps: float

    @property
    def num_frames(self) -> int:
        return len(self.times_t)

    def quaternions_tj4(self) -> np.ndarray:
        """(T, J, 4) local rotations as unit quaternions (x, y, z, w), sign-continuous over time
        (each one in the hemisphere of the frame before, so interpolation takes the short way)."""
        T, J = self.rot_tj33.shape[:2]
        q = Rotation.from_matrix(self.rot_tj33.reshape(-1, 3, 3)).as_quat().reshape(T, J, 4)
        flip = np.cumprod(np.where(np.sum(q[1:] * q[:-1], -1) < 0, -1.0, 1.0), axis=0)
        q[1:] *= flip[..., None]
        return q

    def world_joints_tj3(self) -> np.ndarray:
        """(T, J, 3) world (Z-up) joint positions: forward kinematics of the local transforms."""
        T, J = self.rot_tj33.shape[:2]
        R = np.zeros((T, J, 3, 3))
        p = np.zeros((T, J, 3))
        for j in range(J):  # SMPL-X lists every parent before its children
            par = self.parents[j]
            if par < 0:
                R[:, j], p[:, j] = self.rot_tj33[:, j], self.offset_tj3[:, j]
            else:
                R[:, j] = R[:, par] @ self.rot_tj33[:, j]
                p[:, j] = p[:, par] + np.einsum("tab,tb->ta", R[:, par], self.offset_tj3[:, j])
        return p


def rest_joints_tj3(model, result) -> np.ndarray:
    """(T, J, 3) rest joints of the person's shape (and each frame's expression), canonical frame."""
    J0 = model.np.J_template.astype(np.float64) + np.einsum("jcb,b->jc", model.np.J_shapedirs.astype(np.float64),
                                                            np.asarray(result.betas, np.float64)[:model.num_betas])
    J_tj3 = np.broadcast_to(J0, (result.num_frames, *J0.shape))
    if model.J_exprdirs is not None:
        E = model.num_expression
        J_tj3 = J_tj3 + np.einsum("jce,te->tjc", model.J_exprdirs.numpy().astype(np.float64), result.expression[:, :E])
    return np.ascontiguousarray(J_tj3)


def skeleton_motion(model, result) -> SkeletonMotion:
    """The person of ``result`` (core.smplxfile.SmplxResult) on ``model``'s skeleton."""
    T = result.num_frames
    aa_tj3 = sk.joint_axis_angles(result)
    rot = Rotation.from_rotvec(aa_tj3.reshape(-1, 3)).as_matrix().reshape(T, -1, 3, 3)
    J_tj3 = rest_joints_tj3(model, result)
    parents = np.asarray(model.np.parents, np.int64)
    offset = J_tj3 - np.where(parents[None, :, None] < 0, 0.0, J_tj3[:, np.maximum(parents, 0)])
    offset[:, 0] = J_tj3[:, 0] + result.transl
    return SkeletonMotion(list(model.joint_names), parents, np.asarray(result.frame_times, np.float64), rot, offset,
                          J_tj3[0].copy(), float(result.fps))


def uniform_frames(times_t: np.ndarray, fps: float) -> tuple[np.ndarray, int]:
    """Where each fitted frame falls on a grid at ``fps`` from the first one, and the grid's length.
    Formats with a fixed rate (BVH, TRC, C3D) write the grid; frames a person was not fitted in
    (they left the views) are the grid's gaps."""
    idx = np.round((np.asarray(times_t) - times_t[0]) * fps).astype(np.int64)
    n = np.arange(len(idx))
    idx = np.maximum.accumulate(idx - n) + n  # clock jitter never puts two frames on one slot
    return idx, int(idx[-1]) + 1 if len(idx) else 0
