"""OpenSim reads the TRC export: its own TimeSeriesTableVec3 loads each person's marker file, and
every marker at every frame is compared with the fitted surface points (OpenSim 4.6 from PyPI, in
a venv of its own: `python3.11 -m venv /tmp/osimenv && /tmp/osimenv/bin/pip install opensim`).

    .venv/bin/mamma-kit export WS --format trc --out /tmp/osim
    .venv/bin/python benchmarks/opensim_import.py --reference WS /tmp/osim
    /tmp/osimenv/bin/python benchmarks/opensim_import.py WS /tmp/osim

With --reference (the project's venv) it writes /tmp/osim/person_<k>.ref.npy: the fitted markers
(Y up, mm) on the TRC's frame grid, NaN where the person was not fitted.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def write_reference(ws: Path, folder: Path) -> None:
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.smplxfile import read_smplx_result
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.export.markers import marker_positions
    from mamma_kit.export.motion import Z_UP_TO_Y_UP, uniform_frames

    w = Workspace(ws)
    model = load_body_model(w.load_capture().body_model)
    for p in w.person_files():
        r = read_smplx_result(p)
        _, xyz = marker_positions(model, r)
        grid, n = uniform_frames(r.frame_times, r.fps)
        out = np.full((n, xyz.shape[1], 3), np.nan)
        out[grid] = xyz @ Z_UP_TO_Y_UP.T * 1000.0
        np.save(folder / f"{p.stem}.ref.npy", out)
        print(f"{p.stem}: {n} frames, {xyz.shape[1]} markers")


def read_in_opensim(folder: Path) -> None:
    import opensim as osim

    print(f"OpenSim {osim.GetVersionAndDate()}")
    for trc in sorted(folder.glob("person_*.trc")):
        t = osim.TimeSeriesTableVec3(str(trc))
        ref = np.load(folder / f"{trc.stem}.ref.npy")
        got = np.array([[[t.getRowAtIndex(i)[m].get(k) for k in range(3)] for m in range(t.getNumColumns())]
                        for i in range(t.getNumRows())])
        ok = ~np.isnan(ref[..., 0])
        print(f"{trc.name}: {t.getNumRows()} frames, {t.getNumColumns()} markers ({', '.join(list(t.getColumnLabels())[:3])}, "
              f"...), {t.getTableMetaDataAsString('DataRate')} Hz, {t.getTableMetaDataAsString('Units')}; "
              f"largest difference from the fitted markers {np.abs(got[ok] - ref[ok]).max():.4f} mm; "
              f"{int((~ok[:, 0]).sum())} frames without the person"
              + (f", read as missing: {bool(np.isnan(got[~ok]).all())}" if (~ok).any() else ""))


if __name__ == "__main__":
    if sys.argv[1] == "--reference":
        write_reference(Path(sys.argv[2]), Path(sys.argv[3]))
    else:
        read_in_opensim(Path(sys.argv[2]))
