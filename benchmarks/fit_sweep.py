"""One fit setting swept on fitted synthetic captures: MPJPE against the truth per value.

    python benchmarks/fit_sweep.py WORKSPACE [WORKSPACE ...] --param gamma --values 2,2.5,4 [--stages 3]

WORKSPACE: a fitted synthetic capture (e.g. `mamma-kit demo --out DIR`). For each value of the
FitConfig field --param, a fresh copy of each workspace is fitted (stages 1-3 unless --stages) with
that value and the rest at their defaults, and compared with the truth: MPJPE of all joints, the
body's and the hands', PA-MPJPE. Each workspace's line says how many hands the hand model read and
was sure of (what the hand points can use).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def parse(text: str, default):
    """A --values item as the field's type (a bool from true/false, 1/0, on/off)."""
    if isinstance(default, bool):
        return text.strip().lower() in ("true", "1", "on", "yes")
    return type(default)(text)


def main() -> None:
    from mamma_kit.core.tracks import KeypointTracks
    from mamma_kit.fitting.stages import FitConfig
    from refit import fresh_copy, refit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("workspaces", type=Path, nargs="+")
    ap.add_argument("--param", default="hand_keypoint_weight", help="a FitConfig field")
    ap.add_argument("--values", default="0,0.1", help="its values, comma-separated")
    ap.add_argument("--stages", type=int, default=3)
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/fit_sweep"))
    a = ap.parse_args()
    default = getattr(FitConfig(), a.param)
    print(f"command: {' '.join(sys.argv)}  (default {a.param} = {default})")
    for src in a.workspaces:
        files = sorted((src / "keypoints").glob("*.npz"))
        flags = np.concatenate([KeypointTracks.load(f).hand_presence.ravel() for f in files]) if files else np.zeros(0)
        read, sure = int((flags > 0).sum()), int((flags > 0.5).sum())
        print(f"\n{src}: {read} hands read, the hand model sure of {sure} ({100 * sure / max(read, 1):.1f} %)")
        print(f"| {a.param} | MPJPE mm | body | hands | PA-MPJPE mm | hands PA | fit s |")
        print("|---|---|---|---|---|---|---|")
        for v in (parse(x, default) for x in a.values.split(",")):
            ws = fresh_copy(src, a.scratch / f"{src.name}-{a.param}-{v}")
            t0 = time.perf_counter()
            m = refit(ws, stages=a.stages, config=dataclasses.replace(FitConfig(), **{a.param: v}))
            print(f"| {v} | {m['mpjpe_mm']:.1f} | {m['mpjpe_body_mm']:.1f} | {m['mpjpe_hands_mm']:.1f} | "
                  f"{m['pa_mpjpe_mm']:.1f} | {m['pa_mpjpe_hands_mm']:.1f} | {time.perf_counter() - t0:.0f} |",
                  flush=True)


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
