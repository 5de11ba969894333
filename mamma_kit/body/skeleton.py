"""SMPL-X skeleton facts shared by every body model: 55 joint names and parents, the
parameter layout, and the body-part vocabulary used for clothing colours and evaluation.

Nothing here depends on a model file: the open body and real SMPL-X files share them.
"""

from __future__ import annotations

import numpy as np

_HAND = ["index1", "index2", "index3", "middle1", "middle2", "middle3", "pinky1", "pinky2", "pinky3",
         "ring1", "ring2", "ring3", "thumb1", "thumb2", "thumb3"]

#: The 55 SMPL-X joints in SMPL-X order.
JOINT_NAMES: list[str] = [
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar",
    "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "jaw", "left_eye_smplhf", "right_eye_smplhf",
] + [f"left_{n}" for n in _HAND] + [f"right_{n}" for n in _HAND]

#: SMPL-X kinematic tree: parent joint index of each joint (-1 for the pelvis), shape (55,).
PARENTS: np.ndarray = np.array(
    [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
     20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
     21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53], dtype=np.int64)

NUM_JOINTS = 55
NUM_BETAS = 16
NUM_EXPRESSION = 10

#: Per-frame parameter vector (DESIGN.md): name -> size of the last dimension, in the
#: order the joints appear in SMPL-X's full pose (global, body, jaw, eyes, hands).
POSE_PARAMS: dict[str, int] = {
    "global_orient": 3, "body_pose": 63, "jaw_pose": 3, "leye_pose": 3, "reye_pose": 3,
    "left_hand_pose": 45, "right_hand_pose": 45,
}


def joint_axis_angles(result) -> np.ndarray:
    """(T, 55, 3) float64 axis-angle of every joint in SMPL-X order, from an object with the pose
    parameters as (T, n) attributes (a core.smplxfile.SmplxResult)."""
    T = len(np.asarray(result.global_orient))
    return np.concatenate([np.asarray(getattr(result, k), np.float64).reshape(T, n) for k, n in POSE_PARAMS.items()],
                          1).reshape(T, -1, 3)


#: Every parameter and its size (betas per person, the rest per frame).
PARAM_SIZES: dict[str, int] = {"betas": NUM_BETAS, **POSE_PARAMS, "expression": NUM_EXPRESSION, "transl": 3}

#: Body parts for per-vertex labels (clothing colours, contact summaries).
PART_NAMES: list[str] = [
    "head", "neck", "torso", "pelvis",
    "left_upper_arm", "right_upper_arm", "left_lower_arm", "right_lower_arm", "left_hand", "right_hand",
    "left_upper_leg", "right_upper_leg", "left_lower_leg", "right_lower_leg", "left_foot", "right_foot",
]


def _joint_part(name: str) -> str:
    side = "left_" if name.startswith("left_") else "right_" if name.startswith("right_") else ""
    base = name[len(side):]
    if name in ("head", "jaw") or "eye" in name:
        return "head"
    if name == "neck":
        return "neck"
    if name == "pelvis":
        return "pelvis"
    if base in ("collar",) or name.startswith("spine"):
        return "torso"
    table = {"shoulder": "upper_arm", "elbow": "lower_arm", "wrist": "hand", "hip": "upper_leg",
             "knee": "lower_leg", "ankle": "foot", "foot": "foot"}
    if base in table:
        return side + table[base]
    if any(base.startswith(f) for f in ("index", "middle", "pinky", "ring", "thumb")):
        return side + "hand"
    raise ValueError(name)


#: Body part of each joint's skinning region, shape (55,) indices into PART_NAMES.
JOINT_PART: np.ndarray = np.array([PART_NAMES.index(_joint_part(n)) for n in JOINT_NAMES], dtype=np.int64)

#: Landmark part labels for evaluation splits (paper: body, hands, head, feet).
LANDMARK_PART_NAMES: list[str] = ["body", "left_hand", "right_hand", "head", "left_foot", "right_foot"]
#: PART_NAMES index -> LANDMARK_PART_NAMES index.
PART_TO_LANDMARK_PART: np.ndarray = np.array(
    [LANDMARK_PART_NAMES.index(p) if p in LANDMARK_PART_NAMES else 0 for p in PART_NAMES], dtype=np.int64)

#: Extra surface keypoints (smplx's vertex_joint_selector order: face, feet, fingertips).
EXTRA_JOINT_NAMES: list[str] = [
    "nose", "right_eye", "left_eye", "right_ear", "left_ear",
    "left_big_toe", "left_small_toe", "left_heel", "right_big_toe", "right_small_toe", "right_heel",
    "left_thumb_tip", "left_index_tip", "left_middle_tip", "left_ring_tip", "left_pinky_tip",
    "right_thumb_tip", "right_index_tip", "right_middle_tip", "right_ring_tip", "right_pinky_tip",
]


def tree_levels(parents: np.ndarray) -> list[np.ndarray]:
    """Joint indices grouped by depth in the tree (level 0 = roots), each sorted.

    Forward kinematics processes one level at a time: every joint of a level has its
    parent in an earlier level, so a level is one batched matrix product.
    """
    parents = np.asarray(parents, dtype=np.int64)
    depth = np.full(len(parents), -1, dtype=np.int64)
    for j in range(len(parents)):  # parents precede children in SMPL-X order
        p = parents[j]
        if p >= j:
            raise ValueError("parents must precede their children")
        depth[j] = 0 if p < 0 else depth[p] + 1
    return [np.flatnonzero(depth == d) for d in range(depth.max() + 1)]
