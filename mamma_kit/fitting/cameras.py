"""Choosing K of a rig's cameras by farthest-point sampling (the paper's camera-count study).

Each camera is a point (centre / rig radius, viewing direction): the first camera of the
rig starts the set, then the camera farthest (in that space) from every chosen one joins,
until K are chosen. Centres are scaled by the rig's radius (median distance of the centres
from their mean), so position and direction weigh alike whatever the rig's size.
"""

from __future__ import annotations

import numpy as np

from mamma_kit.core.camera import Rig
from mamma_kit.core.errors import UserError


def camera_features(rig: Rig, direction_weight: float = 1.0) -> np.ndarray:
    """(C, 6): centre / radius and unit optical axis x weight."""
    C = rig.centers()
    radius = float(np.median(np.linalg.norm(C - C.mean(0), axis=1))) if len(C) > 1 else 1.0
    radius = radius if radius > 1e-9 else 1.0
    axes = np.stack([cam.R[2] for cam in rig])
    return np.concatenate([(C - C.mean(0)) / radius, direction_weight * axes], 1)


def pick_cameras(rig: Rig, count: int, start: str | None = None, direction_weight: float = 1.0) -> list[str]:
    """Names of ``count`` cameras chosen by farthest-point sampling, in the order chosen."""
    n = len(rig)
    if count < 1:
        raise UserError(f"--count {count} must be at least 1", "pass e.g. --count 4")
    if count > n:
        raise UserError(f"asked for {count} cameras, the calibration has {n}", f"pass --count {n} or fewer")
    f = camera_features(rig, direction_weight)
    first = rig.names.index(start) if start else 0
    chosen = [first]
    d = np.linalg.norm(f - f[first], axis=1)
    while len(chosen) < count:
        d_masked = d.copy()
        d_masked[chosen] = -np.inf
        nxt = int(np.argmax(d_masked))
        chosen.append(nxt)
        d = np.minimum(d, np.linalg.norm(f - f[nxt], axis=1))
    return [rig.names[i] for i in chosen]
