"""BVH: one person's SMPL-X skeleton (55 joints) with its rest offsets and per-frame rotations,
the root's position, Y up, centimetres (Blender's BVH importer: scale 0.01 for metres).

BVH has one frame rate and no gaps: frames are written on the grid of the fit's rate from the
person's first fitted frame, and a frame the person was not fitted in repeats the last one.
Rotation channels are Z, X, Y Euler angles in degrees (R = Rz Rx Ry), the common order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mamma_kit.export.motion import Z_UP_TO_Y_UP, SkeletonMotion, uniform_frames

CM_PER_M = 100.0
EULER = "ZXY"  # scipy's intrinsic order for the channels Zrotation Xrotation Yrotation


def _hierarchy(motion: SkeletonMotion, offsets_j3: np.ndarray) -> list[str]:
    children = {j: [int(c) for c in np.flatnonzero(motion.parents == j)] for j in range(len(motion.names))}
    lines: list[str] = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "\t" * depth
        root = motion.parents[j] < 0
        lines.append(f"{pad}{'ROOT' if root else 'JOINT'} {motion.names[j]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}\tOFFSET {' '.join(f'{x:.6f}' for x in offsets_j3[j])}")
        chans = "CHANNELS 6 Xposition Yposition Zposition" if root else "CHANNELS 3"
        lines.append(f"{pad}\t{chans} Zrotation Xrotation Yrotation")
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:  # BVH wants an end to every chain
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET 0.000000 0.000000 0.000000", f"{pad}\t}}"])
        lines.append(f"{pad}}}")

    emit(int(np.flatnonzero(motion.parents < 0)[0]), 0)
    return lines


def depth_first(parents: np.ndarray) -> list[int]:
    """Joint ids in the order BVH lists them (depth first, children in id order)."""
    order: list[int] = []

    def visit(j: int) -> None:
        order.append(j)
        for c in np.flatnonzero(parents == j):
            visit(int(c))

    visit(int(np.flatnonzero(parents < 0)[0]))
    return order


def write_bvh(path: str | Path, motion: SkeletonMotion) -> dict:
    """Write the motion; returns a summary (frames on the grid, frames repeated over gaps)."""
    from mamma_kit.core.io import atomic_write_bytes

    idx, n = uniform_frames(motion.times_t, motion.fps)
    src = np.searchsorted(idx, np.arange(n), side="right") - 1  # each grid frame: the last fitted one
    offsets = motion.offset_tj3[0].copy()
    offsets[motion.parents < 0] = 0.0  # the root's place is its position channels
    rot = motion.rot_tj33[src]
    rot[:, motion.parents < 0] = Z_UP_TO_Y_UP @ rot[:, motion.parents < 0]
    root_pos = motion.offset_tj3[src][:, motion.parents < 0][:, 0] @ Z_UP_TO_Y_UP.T * CM_PER_M
    order = depth_first(motion.parents)
    euler = Rotation.from_matrix(rot[:, order].reshape(-1, 3, 3)).as_euler(EULER, degrees=True).reshape(n, -1)
    values = np.concatenate([root_pos, euler], 1)
    lines = _hierarchy(motion, offsets * CM_PER_M)
    lines += ["MOTION", f"Frames: {n}", f"Frame Time: {1.0 / motion.fps:.8f}"]
    lines += [" ".join(f"{x:.5f}" for x in row) for row in values]
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())
    return {"path": str(path), "frames": n, "repeated": int(n - len(idx)), "joints": len(motion.names)}
