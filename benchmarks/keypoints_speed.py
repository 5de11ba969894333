"""Speed of BlazePose keypoints and of the `pose` tracker on 2 CPU cores, video decoding included.

Input: the real 4-camera recording in ../shared/real/pose2sim-multiperson (1088x1920 portrait H.264,
60 fps, 100 frames per camera, two people). The workspace is made in --root with `init
--calibration`; `track --backend pose --people 2` runs first (timed: frames per second), then
`keypoints` (timed: person-frames per second, the issue's target is >= 40). Each figure is the
best of --repeat runs (the others are printed too), since a shared machine only ever slows a run.

    python benchmarks/keypoints_speed.py --root /work/bench/kps
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("bench_data/kps"))
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--threads", type=int, default=2, help="LiteRT threads")
    args = ap.parse_args()
    from real_workspace import real_workspace

    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.keypoints.estimator import PoseEstimator
    from mamma_kit.keypoints.stage import keypoints_for_tracks
    from mamma_kit.masks.base import CameraInput
    from mamma_kit.masks.pose import PoseBackend

    ws = real_workspace(args.root)
    cap = ws.load_capture()
    backend = PoseBackend(threads=args.threads)
    track_fps, kp_rates = [], []
    for r in range(args.repeat):
        frames, t0 = 0, time.perf_counter()
        for c in cap.camera_names:
            mt, _ = backend.track_camera(CameraInput(c, cap.cameras[c].video, ws.root))
            mt.save(ws.mask_file(c))
            frames += len(mt.frame_times)
        track_fps.append(frames / (time.perf_counter() - t0))
        est = PoseEstimator(args.threads)
        n, t0 = 0, time.perf_counter()
        for c in cap.camera_names:
            mt = MaskTracks.load(ws.mask_file(c))
            kt, summ = keypoints_for_tracks(est, mt, cap.cameras[c].video)
            n += summ["instances"]
        kp_rates.append(n / (time.perf_counter() - t0))
        print(f"run {r + 1}: track --backend pose {track_fps[-1]:.1f} frames/s; keypoints {kp_rates[-1]:.1f} "
              f"person-frames/s ({n} person-frames, 4 cameras, 1088x1920, decoding included)", flush=True)
    print(f"best: track --backend pose {max(track_fps):.1f} frames/s, keypoints {max(kp_rates):.1f} person-frames/s "
          f"on {args.threads} LiteRT threads (target >= 40 person-frames/s)")


if __name__ == "__main__":
    main()
