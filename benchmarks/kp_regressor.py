"""Learn the vertex -> BlazePose-point regressor (mamma_kit/body/kp_regressor.py) and measure it
on captures and seeds it never saw.

Each capture is rendered by `mamma-kit synth` on first use, its people tracked with their true
masks (`track --backend gt`, so a track id is the person id) and BlazePose run on them
(`mamma-kit keypoints`). The regressor learns on TRAIN; on HELDOUT it prints, per point group,
the median distance between BlazePose's detections (visibility > 0.5) and the true bodies'
points projected into the camera, in % of the person's true box height, for the naive
correspondence (skeleton joints, named vertices), the initial guess (anchors) and the learned
regressor. --write rewrites the shipped file (mamma_kit/body/data/open_body_blazepose33.npz).

    OMP_NUM_THREADS=1 nice -n 15 python benchmarks/kp_regressor.py --root /work/tmp/kpreg [--write]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

# folder: (recipe, seed, frames, render scale)
TRAIN = {"duo7": ("iphone-outdoor-duo", 7, 30, 0.5), "crowd31": ("crowd-6", 31, 30, 0.5),
         "studio103": ("studio-16cam-solo", 103, 30, 0.25), "duo1618": ("iphone-outdoor-duo", 1618, 100, 0.25)}
HELDOUT = {"duo2718": ("iphone-outdoor-duo", 2718, 100, 0.25), "studio3141": ("studio-16cam-solo", 3141, 100, 0.25)}
GROUPS = {"face": range(0, 11), "shoulders": (11, 12), "elbows": (13, 14), "wrists": (15, 16),
          "hands": range(17, 23), "hips": (23, 24), "knees": (25, 26), "ankles": (27, 28), "heels": (29, 30),
          "toes": (31, 32)}


def mk(*args) -> None:
    cmd = [sys.executable, "-c", "import sys; from mamma_kit.cli.app import main; main(sys.argv[1:])", *map(str, args)]
    subprocess.run(cmd, check=True)


def prepare(root: Path, name: str, recipe: str, seed: int, frames: int, scale: float) -> Path:
    ws = root / name
    if not (ws / "gt" / "synth.json").is_file():
        mk("synth", recipe, "--out", ws, "--seed", seed, "--frames", frames, "--scale", scale, "--no-board", "-q")
    if not (ws / "keypoints").is_dir():
        mk("track", ws, "--backend", "gt", "--quiet", "--no-pictures")
        mk("keypoints", ws, "--threads", 1, "--quiet", "--no-pictures")
    return ws


def table(errs: dict[str, np.ndarray], vis: np.ndarray) -> dict[str, dict[str, float]]:
    out = {}
    for g, ks in GROUPS.items():
        ks = list(ks)
        out[g] = {m: float(np.median(e[:, ks][vis[:, ks]]) * 100) for m, e in errs.items()}
    out["all"] = {m: float(np.median(e[vis]) * 100) for m, e in errs.items()}
    out["all mean"] = {m: float(np.mean(np.minimum(e[vis], 0.5)) * 100) for m, e in errs.items()}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("bench_data/kpreg"))
    ap.add_argument("--write", action="store_true", help="rewrite the shipped regressor file")
    ap.add_argument("--ridge", type=float, default=3e-3)
    a = ap.parse_args()
    from mamma_kit.body import kp_regressor as kr
    from mamma_kit.body.model import load_body_model

    model = load_body_model("open")
    t0 = time.perf_counter()
    train = [prepare(a.root, n, *c) for n, c in TRAIN.items()]
    held = [prepare(a.root, n, *c) for n, c in HELDOUT.items()]
    reg0 = kr.initial_regressor(model)
    det = kr.collect_detections(train, model, reg0)
    print(f"# train: {', '.join(TRAIN)}: {len(det.V)} person-views; held out: {', '.join(HELDOUT)}", flush=True)
    prov = {"made_by": "benchmarks/kp_regressor.py --write", "train": {n: list(c) for n, c in TRAIN.items()},
            "keypoints": "mamma-kit keypoints on ground-truth-mask tracks", "person_views": int(len(det.V))}
    reg = kr.learn_regressor(det, model, reg0, ridge=a.ridge, provenance=prov)
    print(f"# learned in {time.perf_counter() - t0:.0f} s (incl. data); support per point "
          f"{int(np.median((reg.weights > 0).sum(1)))} vertices (median)", flush=True)
    for name, ws in zip(HELDOUT, held):
        dh = kr.collect_detections([ws], model, reg0)
        vis = dh.vis > 0.5
        errs = {"naive": np.linalg.norm(dh.naive_px - dh.xy, axis=-1) / dh.box_h[:, None],
                "initial": kr.regressed_errors(reg0, dh, model), "learned": kr.regressed_errors(reg, dh, model)}
        tab = table(errs, vis)
        print(f"\n{name} ({HELDOUT[name][0]} seed {HELDOUT[name][1]}, {len(dh.V)} person-views): median "
              f"% of the box height, BlazePose vs the true body's points")
        print("| points | naive (joints) | initial guess | learned |")
        print("|---|---|---|---|")
        for g, r in tab.items():
            print(f"| {g} | {r['naive']:.2f} | {r['initial']:.2f} | {r['learned']:.2f} |")
    if a.write:
        path = reg.save(kr.DATA_FILE)
        print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
