"""TRC: marker trajectories as OpenSim and Pose2Sim read them (tab-separated text, millimetres,
Y up as OpenSim's models stand). Frames lie on the grid of the fit's rate; a frame the person
was not fitted in is left empty, which OpenSim's tools treat as a missing marker.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mamma_kit.export.motion import Z_UP_TO_Y_UP

MM_PER_M = 1000.0


def write_trc(path: str | Path, names: list[str], xyz_tm3: np.ndarray, grid_t: np.ndarray, n_frames: int,
              rate: float) -> dict:
    """Markers ``names`` at world positions (T, M, 3) (Z-up metres) on grid frames ``grid_t``."""
    from mamma_kit.core.io import atomic_write_bytes

    path = Path(path)
    M = len(names)
    grid = np.full((n_frames, M, 3), np.nan)
    grid[grid_t] = xyz_tm3 @ Z_UP_TO_Y_UP.T * MM_PER_M
    head = ["PathFileType\t4\t(X/Y/Z)\t" + path.name,
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            f"{rate:g}\t{rate:g}\t{n_frames}\t{M}\tmm\t{rate:g}\t1\t{n_frames}",
            "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
            "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, M + 1)),
            ""]
    rows = []
    for f in range(n_frames):
        cells = ["" if np.isnan(x) else f"{x:.4f}" for x in grid[f].reshape(-1)]
        rows.append(f"{f + 1}\t{f / rate:.6f}\t" + "\t".join(cells))
    atomic_write_bytes(path, ("\n".join(head + rows) + "\n").encode())
    return {"path": str(path), "frames": n_frames, "markers": M, "empty_frames": int(n_frames - len(grid_t))}
