"""C3D: marker trajectories for gait and biomechanics software (Vicon Nexus, Visual3D, Mokka,
OpenSim's C3D reader), written with ezc3d. Millimetres, mamma-kit's Z-up world as lab systems
keep it; frames on the grid of the fit's rate, a frame the person was not fitted in has its
markers invalid (residual -1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

MM_PER_M = 1000.0


def write_c3d(path: str | Path, names: list[str], xyz_tm3: np.ndarray, grid_t: np.ndarray, n_frames: int,
              rate: float) -> dict:
    """Markers ``names`` at world positions (T, M, 3) (Z-up metres) on grid frames ``grid_t``."""
    import ezc3d

    from mamma_kit.core.io import atomic_path

    path = Path(path)
    M = len(names)
    pts = np.zeros((4, M, n_frames))
    pts[3] = 1.0
    pts[:3, :, grid_t] = (xyz_tm3 * MM_PER_M).transpose(2, 1, 0)
    residuals = np.full((1, M, n_frames), -1.0)
    residuals[:, :, grid_t] = 0.0
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(rate)]
    c["parameters"]["POINT"]["LABELS"]["value"] = list(names)
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c["data"]["points"] = pts
    c["data"]["meta_points"] = {"residuals": residuals}
    with atomic_path(path) as tmp:
        c.write(str(tmp))
    return {"path": str(path), "frames": n_frames, "markers": M, "empty_frames": int(n_frames - len(grid_t))}
