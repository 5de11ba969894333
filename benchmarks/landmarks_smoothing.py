"""The landmarks stage's smoothing of contact and visibility (landmarks/smooth.py), swept on synthetic
captures against the renderer's truth.

    python benchmarks/landmarks_smoothing.py WORKSPACE [WORKSPACE ...] [--sigmas 0,0.05,0.1,0.15] [--ks 1,4,8]
        [--contact auto|off]

WORKSPACE: a synthetic capture with person masks and keypoints (e.g. `mamma-kit demo --out DIR`). In a
copy (WORKSPACE-smoothing-<contact>), `mamma-kit landmarks --smooth-s 0 --contact C` writes the
network's raw landmarks once (--contact off: embedded-kp's own contact head, as the README's figures); each (sigma in seconds, k nearest landmarks for contact) is then applied in memory and judged
by `mamma-kit eval`'s landmark metrics: person-contact ROC AUC and visibility accuracy (the 2D
positions do not change).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path


def main() -> None:
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.tracks import LandmarkTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.landmarks import evaluate
    from mamma_kit.landmarks.smooth import landmark_neighbours, smooth_probabilities

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("workspaces", nargs="+", type=Path)
    ap.add_argument("--sigmas", default="0,0.05,0.1,0.15", help="seconds, comma-separated")
    ap.add_argument("--ks", default="1,4,8", help="nearest landmarks averaged for contact")
    ap.add_argument("--contact", default="auto", help="the landmarks stage's --contact (auto or off)")
    a = ap.parse_args()
    print("command: benchmarks/landmarks_smoothing.py " + " ".join(sys.argv[1:]))
    body = load_body_model("open")
    rest_l3 = body.np.v_template[body.landmark_ids]
    for src in a.workspaces:
        dst = src.with_name(f"{src.name}-smoothing-{a.contact}")
        if not (dst / "landmarks").is_dir():
            shutil.rmtree(dst, ignore_errors=True)
            top = str(src.resolve())
            shutil.copytree(src, dst, ignore=lambda d, names: [n for n in names if str(Path(d).resolve()) == top
                                                                and n in ("report", "smplx", "landmarks")])
            subprocess.run(["mamma-kit", "landmarks", str(dst), "--smooth-s", "0", "--contact", a.contact, "-q"],
                           check=True)
        ws = Workspace(dst)
        raw = {p.stem: LandmarkTracks.load(p) for p in sorted(ws.landmarks_dir.glob("*.npz"))}
        print(f"\n{src}: {len(raw)} cameras")
        print("| sigma s | k | person-contact AUC | visibility accuracy % | floor-contact AUC |")
        print("|---|---|---|---|---|")
        for s in [float(x) for x in a.sigmas.split(",")]:
            for k in [int(x) for x in a.ks.split(",")]:
                nn = landmark_neighbours(rest_l3, k) if k > 1 else None
                m = evaluate(ws, {c: smooth_probabilities(lt, s, nn) for c, lt in raw.items()})
                print(f"| {s:g} | {k} | {m['contact_auc']:.4f} | {100 * m['visibility_accuracy']:.2f} | "
                      f"{m['floor_contact_auc']:.4f} |", flush=True)


if __name__ == "__main__":
    main()
