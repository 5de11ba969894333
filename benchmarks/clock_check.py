"""The fit's clock check (fitting/viewcheck.clock_findings, timing/crosscheck.py) on a workspace's
keypoints, as timed and with one camera's clock shifted in timing.toml: which camera it names, by
how much. No fit is needed: the check reads the keypoints the fit reads, on its frames.

    python benchmarks/clock_check.py WS [--shifts cam3:0.3,cam2:-0.2,cam1:0.12] [--out /tmp/clock_check]

WS: a workspace through `match` (calibration, timing.toml, keypoints, identities). Each case is a
hard-linked copy of it with its own timing.toml; the first line is the workspace as it is.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tomllib
from pathlib import Path


def check(root: Path) -> list:
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.fitting.data import open_fit_data
    from mamma_kit.fitting.viewcheck import clock_findings

    d = open_fit_data(Workspace(root))
    return clock_findings(d.rig, d.frame_times, d.kp_xy, d.kp_vis, list(d.person_ids))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("ws", type=Path)
    ap.add_argument("--shifts", default="cam3:0.3", help="camera:seconds added to its offset_s, comma-separated")
    ap.add_argument("--out", type=Path, default=Path("/tmp/clock_check"))
    a = ap.parse_args()
    import tomli_w

    from mamma_kit.core import log

    log.set_quiet(True)
    cases = [("as timed", None, 0.0)] + [(s, s.split(":")[0], float(s.split(":")[1])) for s in a.shifts.split(",")]
    print(f"{a.ws}: the clock check")
    print("| timing.toml | cameras named | what it says |")
    print("|---|---|---|")
    for label, cam, by in cases:
        root = a.ws
        if cam is not None:
            root = a.out / label.replace(":", "_")
            if root.exists():
                shutil.rmtree(root)
            shutil.copytree(a.ws, root, copy_function=os.link, ignore=shutil.ignore_patterns("timing.toml"))
            doc = tomllib.loads((a.ws / "timing.toml").read_text())
            doc["cameras"][cam]["offset_s"] = float(doc["cameras"][cam]["offset_s"]) + by
            (root / "timing.toml").write_text(tomli_w.dumps(doc))
        found = check(root)
        named = sorted({f.what.split("'")[0] for f in found})
        print(f"| {label if cam is None else f'{cam} {by:+.2f} s'} | {', '.join(named) or 'none'} | "
              f"{found[0].what if found else '-'} |", flush=True)


if __name__ == "__main__":
    main()
