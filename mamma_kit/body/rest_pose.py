"""Poses defined against a model's rest pose: the arms lifted into a T-pose, a relaxed hand.

- ``arm_rest_rotations(J_template_j3)``: per arm, the rotation Q that lifts the rest pose's arm
  into a T-pose; T-pose-relative joint rotations R are re-expressed for the model as Q^-1 R Q
  below the shoulder (the synthetic motion library's arms, the fit's relaxed hand).
- ``relaxed_hand_pose(J_template_j3, curl)``: (55, 3) axis-angle, zero except the four fingers'
  nine joints each flexed by ``curl`` rad towards the palm: the hand a person holds when not
  using it, the fit's prior for fingers it cannot see.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mamma_kit.body import skeleton as sk

SIDES = {"left": (16, 20, [1.0, 0.0, 0.0]), "right": (17, 21, [-1.0, 0.0, 0.0])}  # shoulder, wrist, T-pose arm
# flexion axis of the four fingers in the T-pose (SMPL-X canonical axes: Y up, facing +Z); a left
# finger curls about -Z, a right one about +Z
CURL_AXIS = {"left": np.array([0.0, 0.0, -1.0]), "right": np.array([0.0, 0.0, 1.0])}
FOUR_FINGERS = ("index", "middle", "pinky", "ring")


def arm_rest_rotations(J_template_j3: np.ndarray) -> dict[str, Rotation]:
    """Rotations Q that lift each arm of a model's rest pose into a T-pose (shoulder->wrist
    along +-X). T-pose-relative arm angles (like SMPL-X's rest pose) need them re-expressed
    for models whose rest pose is an A-pose (the open body)."""
    out = {}
    for side, (s, w, target) in SIDES.items():
        d = J_template_j3[w] - J_template_j3[s]
        d = d / np.linalg.norm(d)
        axis = np.cross(d, target)
        ang = np.arccos(np.clip(d @ np.asarray(target), -1, 1))
        out[side] = Rotation.from_rotvec(axis / max(np.linalg.norm(axis), 1e-12) * ang)
    return out


def relaxed_hand_pose(J_template_j3: np.ndarray, curl: float) -> np.ndarray:
    """(55, 3) axis-angle local rotations: each joint of the four fingers flexed by ``curl`` rad
    (the thumb and every other joint at rest)."""
    pose_j3 = np.zeros((sk.NUM_JOINTS, 3))
    for side, Q in arm_rest_rotations(J_template_j3).items():
        R = Q.inv() * Rotation.from_rotvec(CURL_AXIS[side] * curl) * Q
        for finger in FOUR_FINGERS:
            for k in (1, 2, 3):
                pose_j3[sk.JOINT_NAMES.index(f"{side}_{finger}{k}")] = R.as_rotvec()
    return pose_j3
