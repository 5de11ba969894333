"""HandNet's sigma on video frames, against the body network's, on held-out synthetic captures.

    python benchmarks/hand_sigma.py WEIGHTS WORKSPACE... [--write]

Each WORKSPACE is a synthetic capture with person tracks and keypoints (e.g. `mamma-kit synth
iphone-outdoor-duo --seed 303 --scale 0.5 --frames 45 --no-board`, `track --backend gt`,
`keypoints`). Its landmarks are made twice, by the body network alone and with HandNet's own hand
landmarks in their place (no averaging, sigma as the network says), and compared with the truth
over the visible hand landmarks: median error / sigma and mean error (% of the box height).

HandNet learns its sigma on crops and comes out too sure of itself on video frames; the ratio of
the two medians is the scale that makes it as sure as the body network's hands (whose sigma the
fit's settings were made with). ``--write`` stores it as ``sigma_scale`` in the weights' card,
which hands.HandRefiner applies. The workspaces' landmarks are left as the body network made them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def measure(weights: Path, workspaces: list[Path]) -> dict:
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.landmarks import landmark_pairs
    from mamma_kit.landmarks import hands as H
    from mamma_kit.landmarks.stage import run_landmarks

    loaded = H.load_hand_weights(weights)
    parts = H.landmark_parts()
    hid = np.concatenate(H.hand_landmark_ids(*parts))
    out = {}
    for name in ("hands", "body"):  # the body network last: the workspaces keep its landmarks
        ratio, err = [], []
        for w in workspaces:
            ws = Workspace(w)
            hands = H.HandRefiner(loaded, *parts, sigma_scale=1.0, fuse=False) if name == "hands" else "off"
            run_landmarks(ws, hands=hands, force=True)
            for cam in ws.load_capture().camera_names:
                got = landmark_pairs(ws, cam)
                if got is None:
                    continue
                d = got[0]
                vis = d["vis_g"][:, hid] > 0.5
                r = np.linalg.norm(d["xy_p"][:, hid] - d["xy_g"][:, hid], axis=-1)
                ratio.append((r / d["sigma_p"][:, hid].mean(-1))[vis])
                err.append((r / d["box_h"][:, None] * 100)[vis])
        if not ratio:
            raise SystemExit("no camera of the workspaces has ground-truth landmarks to compare with")
        out[name] = {"median_err_over_sigma": float(np.median(np.concatenate(ratio))),
                     "visible_error_pct": float(np.concatenate(err).mean())}
    out["sigma_scale"] = out["hands"]["median_err_over_sigma"] / out["body"]["median_err_over_sigma"]
    return out


def main() -> None:
    from mamma_kit.core import log

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("weights", type=Path)
    ap.add_argument("workspaces", type=Path, nargs="+")
    ap.add_argument("--write", action="store_true", help="store the scale in the weights' card")
    a = ap.parse_args()
    log.set_quiet(True)
    m = measure(a.weights, a.workspaces)
    for name in ("body", "hands"):
        print(f"{name:6s} visible hand landmarks: error {m[name]['visible_error_pct']:.2f} % of the box height, "
              f"median error / sigma {m[name]['median_err_over_sigma']:.3f}")
    print(f"sigma scale {m['sigma_scale']:.3f}")
    if a.write:
        from mamma_kit.landmarks.hands import load_hand_weights, save_hand_weights

        loaded = load_hand_weights(a.weights)
        card = {**loaded.card, "sigma_scale": m["sigma_scale"],
                "calibration": {**m, "workspaces": [str(w) for w in a.workspaces]}}
        print(save_hand_weights(a.weights, loaded.model, loaded.landmark_set, card))
    print(json.dumps(m))


if __name__ == "__main__":
    main()
