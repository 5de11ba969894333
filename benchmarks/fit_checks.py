"""The fit's physical self-checks (mamma_kit/fitting/checks.py, and each view against the bodies:
fitting/viewcheck.py) on fitted workspaces, without fitting again: the bodies from smplx/, who was
seen where and each view's landmarks from the fit's inputs.

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
    from mamma_kit.body import skeleton as sk
    from mamma_kit.fitting.stage import physical_checks
    from mamma_kit.fitting.viewcheck import camera_findings, gather

    ws = Workspace(root)
    res = {int(p.stem.split("_")[1]): read_smplx_result(p) for p in ws.person_files()}
    model = load_body_model(ws.load_capture().body_model)
    data = open_fit_data(ws, n_landmarks=len(model.landmark_ids))
    pids = [p for p in data.person_ids if p in res]
    seen = data.present[:, [data.person_ids.index(p) for p in pids]]
    observed = seen.sum(0) >= min(2, len(data.cameras))  # the fit's observed frames
    T = len(data.frame_times)
    pose = np.stack([sk.joint_axis_angles(res[p]) for p in pids])
    transl = np.stack([res[p].transl for p in pids])
    betas = np.stack([res[p].betas for p in pids])
    cols = [data.person_ids.index(p) for p in pids]
    def blocks():
        from types import SimpleNamespace

        for a in range(0, T, 200):
            s = slice(a, min(a + 200, T))
            d = data.slice_frames(s)
            yield s, SimpleNamespace(xy=d.xy[:, cols], vis=d.vis[:, cols], present=d.present[:, cols])

    kp = (data.kp_xy[:, cols], data.kp_vis[:, cols]) if data.kp_xy is not None else (None, None)
    views = camera_findings(data.rig, *gather(model, blocks(), pose, transl, betas), pids, data.frame_times, *kp)
    return physical_checks(ws, model, data.rig, data.frame_times, np.stack([res[p].joints for p in pids]), observed,
                           seen, betas, pids, views)


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
