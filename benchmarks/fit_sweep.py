"""What the hand model's points (keypoints/hands.py) do to the fit of a synthetic capture.

    python benchmarks/hand_fit_effect.py WORKSPACE [--weights 0,0.1] [--stages 3]

WORKSPACE: a fitted synthetic capture whose keypoints/<cam>.npz hold hands (e.g. `mamma-kit demo
--out DIR`). For each hand_keypoint_weight (0 = the hand points off) a fresh copy is fitted (stages
1-3 unless --stages) and compared with the truth: MPJPE of all joints, the body's and the hands',
PA-MPJPE, and the share of hand readings the fit used (the model sure of the hand).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from mamma_kit.core.tracks import KeypointTracks
    from mamma_kit.fitting.stages import FitConfig
    from refit import fresh_copy, refit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--weights", default="0,0.1", help="hand_keypoint_weight values, comma-separated")
    ap.add_argument("--stages", type=int, default=3)
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/hand_fit_effect"))
    a = ap.parse_args()
    src = fresh_copy(a.workspace, a.scratch / "probe")
    sure = read = 0
    for f in sorted(src.keypoints_dir.glob("*.npz")):
        kt = KeypointTracks.load(f)
        read += int((kt.hand_presence > 0).sum())
        sure += int((kt.hand_presence > 0.5).sum())
    print(f"{a.workspace}: {read} hands read, the model sure of {sure} ({100 * sure / max(read, 1):.1f} %)")
    print("| hand_keypoint_weight | MPJPE mm | body | hands | PA-MPJPE mm | hands PA | fit s |")
    print("|---|---|---|---|---|---|---|")
    for w in (float(x) for x in a.weights.split(",")):
        ws = fresh_copy(a.workspace, a.scratch / f"w{w:g}")
        t0 = time.perf_counter()
        m = refit(ws, stages=a.stages, config=dataclasses.replace(FitConfig(), hand_keypoint_weight=w))
        secs = time.perf_counter() - t0
        print(f"| {w:g} | {m['mpjpe_mm']:.1f} | {m['mpjpe_body_mm']:.1f} | {m['mpjpe_hands_mm']:.1f} | "
              f"{m['pa_mpjpe_mm']:.1f} | {m['pa_mpjpe_hands_mm']:.1f} | {secs:.0f} |", flush=True)


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
