"""The fit's physical self-checks (mamma_kit/fitting/checks.py) on fitted workspaces, without
fitting again: the bodies from smplx/, who was seen where from the fit's inputs.

    python benchmarks/fit_checks.py demo-out /tmp/speed/ws /tmp/meeting/ws
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def checks_of(root: Path) -> dict:
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.smplxfile import read_smplx_result
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.fitting.data import open_fit_data
    from mamma_kit.fitting.stage import physical_checks

    ws = Workspace(root)
    res = {int(p.stem.split("_")[1]): read_smplx_result(p) for p in ws.person_files()}
    model = load_body_model(ws.load_capture().body_model)
    data = open_fit_data(ws, n_landmarks=len(model.landmark_ids))
    pids = [p for p in data.person_ids if p in res]
    seen = data.present[:, [data.person_ids.index(p) for p in pids]]
    observed = seen.sum(0) >= min(2, len(data.cameras))  # the fit's observed frames
    return physical_checks(ws, model, data.rig, data.frame_times, np.stack([res[p].joints for p in pids]), observed,
                           seen, np.stack([res[p].betas for p in pids]), pids)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("workspaces", nargs="+", type=Path)
    args = ap.parse_args()
    from mamma_kit.fitting.checks import summary_lines

    for root in args.workspaces:
        c = checks_of(root)
        print(f"{root}: {'passed' if c['passed'] else 'FAILED'}; impossible person-frames {c['impossible_frames']}, "
              f"doubtful {c['doubtful_frames']}; by check {c['by_check']}; floor known: {c['floor_known']}")
        for line in summary_lines(c, limit=12):
            print("   ", line)


if __name__ == "__main__":
    main()
