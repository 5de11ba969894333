"""Where a synthetic capture's fit error comes from: joints, hands, and the landmarks under them.

    python benchmarks/fit_error_breakdown.py WORKSPACE [--json out.json]

WORKSPACE is a fitted synthetic capture (e.g. `mamma-kit demo --out DIR`). Prints:

- MPJPE (mm) per joint group: trunk, legs, shoulders, elbows, wrists, fingers (25-54), and
  the fingers relative to their wrist (both moved to the true wrist), the part of the hand
  error that the arm does not explain;
- the MPJPE with the true finger poses put into the fit (the wrists and arms as fitted): how
  much better fingers alone could make it;
- the network's landmark error per body part (visible landmarks, % of the box height: mean,
  median, 90th percentile) and its visibility accuracy there, from landmarks/ against
  gt/landmarks/ (matched as in `mamma-kit eval`).

Issue 22 used it to find that the demo's hand error is the arm's (wrist 56-72 mm), not the
fingers', and that the arm's landmarks are what is wrong (hands 4-6 % of the box height).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

GROUPS = {"trunk": [0, 3, 6, 9, 12, 13, 14, 15], "legs": [1, 2, 4, 5, 7, 8, 10, 11], "shoulders": [16, 17],
          "elbows": [18, 19], "wrists": [20, 21], "fingers": list(range(25, 55))}
WRIST_OF = {20: list(range(25, 40)), 21: list(range(40, 55))}  # left, right hand joints


def joint_breakdown(ws, results) -> dict:
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.evaluation.fit import Matched, match_results

    m = match_results(ws, results)
    if not isinstance(m, Matched):
        raise SystemExit(f"cannot compare with ground truth: {m}")
    E, rel, E_gtf = [], [], []
    for fi, gi in m.pairs:
        F, G = m.fit_joints[fi], m.gt_joints[gi]  # (T, 55, 3)
        E.append(np.linalg.norm(F - G, axis=-1) * 1000)
        for w, hj in WRIST_OF.items():
            rel.append(np.linalg.norm((F[:, hj] - F[:, [w]]) - (G[:, hj] - G[:, [w]]), axis=-1).ravel() * 1000)
        prm = {k: v[m.keep] for k, v in results[fi].params().items() if k != "betas"}
        prm |= {"betas": results[fi].betas, "left_hand_pose": m.gt_params[gi]["left_hand_pose"],
                "right_hand_pose": m.gt_params[gi]["right_hand_pose"]}
        J = m.world(pose_mesh_np(m.model, prm)[1].astype(np.float64))
        E_gtf.append(np.linalg.norm(J - G, axis=-1) * 1000)
    E, E_gtf = np.concatenate(E), np.concatenate(E_gtf)
    out = {"mpjpe_mm": float(E.mean()), **{f"{g}_mm": float(E[:, j].mean()) for g, j in GROUPS.items()},
           "fingers_relative_to_wrist_mm": float(np.concatenate(rel).mean()),
           "with_true_finger_poses": {"mpjpe_mm": float(E_gtf.mean()),
                                      "fingers_mm": float(E_gtf[:, GROUPS["fingers"]].mean())}}
    return out


def landmark_breakdown(ws) -> dict:
    from mamma_kit.body import skeleton as sk
    from mamma_kit.body.model import load_body_model
    from mamma_kit.evaluation.landmarks import landmark_pairs

    model = load_body_model("open")
    part_l = model.vertex_part[np.asarray(model.landmark_ids)]
    got = [landmark_pairs(ws, p.stem) for p in sorted(ws.landmarks_dir.glob("*.npz"))]
    ds = [g[0] for g in got if g is not None]
    if not ds:
        return {}
    cat = {k: np.concatenate([d[k] for d in ds]) for k in ("xy_p", "xy_g", "box_h", "vis_g", "vis_p")}
    err = np.linalg.norm(cat["xy_p"] - cat["xy_g"], axis=-1) / cat["box_h"][:, None] * 100  # (N, L) %
    vis = cat["vis_g"] > 0.5
    out = {}
    for p, name in enumerate(sk.PART_NAMES):
        sel = part_l == p
        if not sel.any():
            continue
        e = err[:, sel][vis[:, sel]]
        out[name] = {"landmarks": int(sel.sum()), "mean_pct": float(e.mean()), "median_pct": float(np.median(e)),
                     "p90_pct": float(np.percentile(e, 90)),
                     "visibility_accuracy": float(((cat["vis_p"][:, sel] > 0.5) == vis[:, sel]).mean())}
    return out


def main() -> None:
    from mamma_kit.core.smplxfile import read_smplx_result
    from mamma_kit.core.workspace import Workspace

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    ws = Workspace(a.workspace)
    results = [read_smplx_result(p) for p in ws.person_files()]
    if not results:
        raise SystemExit(f"{a.workspace} has no smplx/person_*.npz: run the fit first")
    joints, parts = joint_breakdown(ws, results), landmark_breakdown(ws)
    print(f"MPJPE {joints['mpjpe_mm']:.1f} mm: " + ", ".join(f"{g} {joints[g + '_mm']:.1f}" for g in GROUPS))
    print(f"fingers relative to their wrist {joints['fingers_relative_to_wrist_mm']:.1f} mm; with the true finger "
          f"poses: MPJPE {joints['with_true_finger_poses']['mpjpe_mm']:.1f}, fingers "
          f"{joints['with_true_finger_poses']['fingers_mm']:.1f} mm")
    print(f"{'landmarks (visible)':18s} {'n':>4s} {'mean %':>7s} {'median':>7s} {'p90':>6s} {'vis acc':>8s}")
    for name, r in parts.items():
        print(f"{name:18s} {r['landmarks']:4d} {r['mean_pct']:7.2f} {r['median_pct']:7.2f} {r['p90_pct']:6.2f} "
              f"{r['visibility_accuracy']:8.3f}")
    if a.json:
        a.json.write_text(json.dumps({"joints": joints, "landmarks": parts}, indent=1))


if __name__ == "__main__":
    main()
