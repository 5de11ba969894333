"""The `pose` tracker and BlazePose keypoints on the real 4-camera recording
(../shared/real/pose2sim-multiperson: synchronised portrait cameras, two people, bystanders).

Builds (or reuses) a workspace in --root (`init --calibration Calib.qca.txt --people 2`,
`track --backend pose --people 2`, `keypoints`), then prints per camera the tracks kept and the
frames each person's track covers, and how well the keypoints agree across views: the points
(visibility > 0.5) triangulated from all four views with the converted Qualisys rig (linear DLT,
core.camera.triangulate_points), reprojected, error in % of the person's box height (its mask's box)
and px. Tracks are paired across views by the assignment with the lowest error.

    python benchmarks/keypoints_real.py --root /work/bench/kps
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np

def reprojection(rig, kts, mts, perm):
    """Errors (% of box height, px) with camera c's track perm[c][p] as person p."""
    C, T = len(kts), min(len(k.frame_times) for k in kts)
    pct, px = [], []
    for p in range(2):
        xy = np.stack([kts[c].xy[:T, perm[c][p]] for c in range(C)])
        w = np.stack([np.where(kts[c].valid[:T, perm[c][p], None], kts[c].visibility[:T, perm[c][p]], 0)
                      for c in range(C)])
        from mamma_kit.core.camera import triangulate_points

        X = triangulate_points(rig, xy.reshape(C, -1, 2), w.reshape(C, -1)).reshape(T, 33, 3)
        h = np.stack([mts[c].boxes[:T, perm[c][p], 3] - mts[c].boxes[:T, perm[c][p], 1] for c in range(C)])
        e = np.linalg.norm(rig.project(X) - xy, axis=-1)
        ok = (w > 0.5) & np.isfinite(e)
        pct.append((e / h[..., None] * 100)[ok])
        px.append(e[ok])
    return np.concatenate(pct), np.concatenate(px)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("bench_data/kps"))
    ap.add_argument("--rerun", action="store_true", help="track and keypoints again even if present")
    args = ap.parse_args()
    from real_workspace import real_workspace

    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.tracks import KeypointTracks, MaskTracks

    ws = real_workspace(args.root, stages=True, force=args.rerun)
    cams = ws.load_capture().camera_names
    mts = [MaskTracks.load(ws.mask_file(c)) for c in cams]
    kts = [KeypointTracks.load(ws.keypoints_file(c)) for c in cams]
    print("| camera | tracks kept | frames with each track | person-frames with keypoints |")
    print("|---|---|---|---|")
    for c, mt, kt in zip(cams, mts, kts):
        print(f"| {c} | {len(mt.track_ids)} | {' / '.join(str(int(n)) for n in mt.present.sum(0))} of "
              f"{len(mt.frame_times)} | {int(kt.valid.sum())} of {int(mt.present.sum())} |")
    rig, _ = read_calibration(ws.calibration)
    rig = rig.subset(cams)
    # the two people's tracks in each view: the pairing (of any two tracks per view; the tracker
    # keeps bystanders too) whose triangulation agrees best
    pairs = [list(itertools.permutations(range(mt.present.shape[1]), 2)) for mt in mts]
    perms = [[pairs[0][0]] + list(rest) for rest in itertools.product(*pairs[1:])] if all(pairs) else []
    scored = [(reprojection(rig, kts, mts, p), p) for p in perms]
    (pct, px), best = min(scored, key=lambda r: np.median(r[0][0]))
    both = np.mean([mt.present[:, list(b)].all(1).mean() for mt, b in zip(mts, best)])
    print(f"both people tracked in {both:.1%} of the (view, frame) pairs")
    print(f"keypoints triangulated from all {len(cams)} views: reprojection median {np.median(pct):.2f} % of the box "
          f"height ({np.median(px):.1f} px), p90 {np.percentile(pct, 90):.1f} %")


if __name__ == "__main__":
    main()
