"""BlazePose keypoints and `pose` masks against synthetic ground truth.

For each capture (rendered by `mamma-kit synth` on first use, from seeds never used while building
the keypoint stage or the pose tracker), three ways to get the people's tracks, then `mamma-kit
keypoints` on each:
  gt       the true masks (the keypoint model alone)
  pose     `track --backend pose --people N`
  builtin  `track --backend builtin --people N` (the background-model tracker)
Printed per way: mask IoU of the tracks (mamma_kit.evaluation.masks), the detection rate (true
(frame, person) pairs with a visible mask of >= 50 px that got keypoints on a track of that person),
and per joint the error of the 33 points against the true body's corresponding joints projected
into the camera, in % of the person's true box height (median over person-frames), with PCK at 10 %.
BlazePose's points and the body model's joints are not defined alike (its hips sit outside the
skeleton's hip joints, its heel and toe points on the skin), so a few % is the floor of this
comparison, not an error of the keypoints.

    nice -n 10 python benchmarks/keypoints_quality.py --root /work/bench/kpq
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

# (label, recipe, folder, frames, render scale, seed)
CASES = [("duo", "iphone-outdoor-duo", "duo_s050_f30_seed7", 30, 0.5, 7),
         ("crowd-6 640x360", "crowd-6", "crowd6_s050_f30_seed31", 30, 0.5, 31),
         ("studio", "studio-16cam-solo", "studio_s025_f30_seed103", 30, 0.25, 103)]
# BlazePose point -> SMPL-X joint (the body model's 55-joint layout)
PAIRS = {"shoulders": ((11, 16), (12, 17)), "elbows": ((13, 18), (14, 19)), "wrists": ((15, 20), (16, 21)),
         "hips": ((23, 1), (24, 2)), "knees": ((25, 4), (26, 5)), "ankles": ((27, 7), (28, 8)),
         "toes": ((31, 10), (32, 11)), "eyes": ((2, 23), (5, 24))}


def true_joints_at(ws, cam: str, times: np.ndarray) -> dict[int, np.ndarray]:
    """Per gt person, its joints (T, 55, 3) at the camera's frame times (through the true clocks)."""
    from mamma_kit.core.timingfile import read_timing

    clocks, _ = read_timing(ws.gt_dir / "timing.toml")
    t_ref = clocks[cam].to_ref(times)
    out = {}
    for f in sorted((ws.gt_dir / "smplx").glob("person_*.npz")):
        d = np.load(f)
        J, ft = d["joints"], d["frame_times"]
        Jt = np.stack([np.stack([np.interp(t_ref, ft, J[:, j, a]) for a in range(3)], -1) for j in range(J.shape[1])], 1)
        out[int(f.stem.split("_")[1])] = Jt
    return out


def evaluate(ws, tracked_by: str) -> dict:
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.tracks import KeypointTracks, MaskTracks
    from mamma_kit.evaluation.masks import compare_camera

    rig, _ = read_calibration(ws.gt_dir / "calibration.toml")
    errs = {k: [] for k in PAIRS}
    found, total, ious = 0, 0, []
    for cam in ws.load_capture().camera_names:
        mt = MaskTracks.load(ws.mask_file(cam))
        gt = MaskTracks.load(ws.gt_dir / "masks" / f"{cam}.npz")
        kt = KeypointTracks.load(ws.keypoints_file(cam))
        ev = compare_camera(mt, gt)
        ious.append(np.nanmean(ev.iou_tp))
        J = true_joints_at(ws, cam, gt.frame_times)
        gcol = {int(p): i for i, p in enumerate(gt.track_ids)}
        for p, Jp in J.items():
            if p not in gcol:
                continue
            g = gcol[p]
            proj = rig[cam].project(Jp)  # (T, 55, 2)
            h = gt.boxes[:, g, 3] - gt.boxes[:, g, 1]
            mine = [k for k, tid in enumerate(mt.track_ids) if ev.track_to_gt.get(int(tid)) == p]
            for t in range(len(gt.frame_times)):
                if not gt.present[t, g] or gt.area(t, g) < 50:
                    continue
                total += 1
                hits = [k for k in mine if t < kt.valid.shape[0] and kt.valid[t, k]]
                if not hits:
                    continue
                found += 1
                k = hits[0]
                for name, pairs in PAIRS.items():
                    for bp_i, sx_j in pairs:
                        errs[name].append(np.linalg.norm(kt.xy[t, k, bp_i] - proj[t, sx_j]) / h[t] * 100)
    allv = np.concatenate([np.asarray(v) for v in errs.values()]) if found else np.zeros(0)
    return {"tracked_by": tracked_by, "mask_iou": float(np.nanmean(ious)), "detected": found / max(total, 1),
            "person_frames": total, "per_joint": {k: float(np.median(v)) if v else float("nan") for k, v in errs.items()},
            "median": float(np.median(allv)) if len(allv) else float("nan"),
            "pck10": float((allv < 10).mean()) if len(allv) else float("nan")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("bench_data/kpq"))
    ap.add_argument("--case", action="append", default=None, help="only these labels (duo, studio, ...)")
    args = ap.parse_args()
    from mamma_kit.cli.app import main as cli
    from mamma_kit.core import log
    from mamma_kit.core.workspace import Workspace

    log.set_quiet(True)
    rows = []
    for label, recipe, folder, frames, scale, seed in CASES:
        if args.case and label not in args.case:
            continue
        path = args.root / folder
        if not (path / "capture.toml").is_file():
            from mamma_kit.synth.capture import synthesize

            print(f"rendering {recipe} seed {seed} ({frames} frames, scale {scale}) into {path}", flush=True)
            synthesize(recipe, path, seed=seed, frames=frames, scale=scale, board=False)
        ws = Workspace(path)
        people = ws.load_capture().people
        for way in ("gt", "pose", "builtin"):
            t0 = time.perf_counter()
            extra = ["--people", str(people)] if way != "gt" and people else []
            for cmd in (["track", str(path), "--backend", way, *extra], ["keypoints", str(path)]):
                try:
                    cli([*cmd, "--force", "--quiet", "--no-pictures"])
                except SystemExit as e:
                    if e.code not in (0, None):
                        raise
            r = evaluate(ws, way)
            r.update(case=label, seconds=time.perf_counter() - t0)
            rows.append(r)
            print(f"{label:16s} {way:8s} masks IoU {r['mask_iou']:.3f}  detected {r['detected']:6.1%} of "
                  f"{r['person_frames']} person-frames  median {r['median']:.2f} %  PCK@10 {r['pck10']:.1%}  "
                  f"({r['seconds']:.0f} s)", flush=True)
    names = list(PAIRS)
    print("\n| capture | tracks | mask IoU | detected | " + " | ".join(names) + " | median % | PCK@10 |")
    print("|---|---|---|---|" + "---|" * len(names) + "---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['tracked_by']} | {r['mask_iou']:.3f} | {r['detected']:.1%} | "
              + " | ".join(f"{r['per_joint'][n]:.1f}" for n in names) + f" | {r['median']:.2f} | {r['pck10']:.1%} |")


if __name__ == "__main__":
    main()
