"""AMASS-style .npz: one person's SMPL-X parameters as AMASS's SMPL-X release stores them, for
code that reads AMASS (human_body_prior, smplx's examples, motion-generation datasets).

poses (T, 165): global, body, jaw, left eye, right eye, left hand, right hand (axis-angle, the
SMPL-X full-pose order); trans (T, 3); betas; num_betas; gender; mocap_framerate;
surface_model_type "smplx"; and the same split as AMASS's newer files (root_orient, pose_body,
pose_hand, pose_jaw, pose_eye). Z up, metres, as AMASS. Hand poses are absolute: load with
smplx's flat_hand_mean=True. mocap_frame_times holds the fitted frames' times (a person who left
the views has gaps that mocap_framerate alone cannot say).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mamma_kit.body import skeleton as sk


def amass_arrays(result) -> dict[str, np.ndarray]:
    """The AMASS-style arrays of a core.smplxfile.SmplxResult."""
    poses = sk.joint_axis_angles(result).reshape(result.num_frames, -1)
    return {"poses": poses, "trans": np.asarray(result.transl, np.float64), "betas": np.asarray(result.betas, np.float64),
            "num_betas": np.array(len(result.betas)), "gender": np.array(result.gender),
            "mocap_framerate": np.array(float(result.fps)), "surface_model_type": np.array("smplx"),
            "root_orient": poses[:, :3], "pose_body": poses[:, 3:66], "pose_jaw": poses[:, 66:69],
            "pose_eye": poses[:, 69:75], "pose_hand": poses[:, 75:165], "expression": np.asarray(result.expression),
            "mocap_frame_times": np.asarray(result.frame_times, np.float64),
            "body_model": np.array([result.body_model_name, result.body_model_sha256])}


def write_amass(path: str | Path, result) -> dict:
    from mamma_kit.core.io import write_npz

    write_npz(path, **amass_arrays(result))
    return {"path": str(path), "frames": result.num_frames}
