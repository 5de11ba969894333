"""Motion sync on the real 4-camera recording (../shared/real/pose2sim-multiperson: synchronised
cameras, so every offset should be 0), and with known shifts put into each camera's frame times.

Builds (or reuses) the workspace of benchmarks/keypoints_speed.py in --root: `init --calibration`,
`track --backend pose --people 2`, `keypoints`; then `timing.motion.motion_clocks`.

    python benchmarks/motion_sync_real.py --root /work/bench/kps
"""

from __future__ import annotations

import argparse
from pathlib import Path

SHIFTS = {"cam02": 0.0373, "cam03": -0.0915, "cam04": 0.2502}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("bench_data/kps"))
    args = ap.parse_args()
    from real_workspace import real_workspace

    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.tracks import KeypointTracks
    from mamma_kit.timing.motion import motion_clocks

    ws = real_workspace(args.root, stages=True)
    cams = ws.load_capture().camera_names
    rig, _ = read_calibration(ws.calibration)
    kts = {c: KeypointTracks.load(ws.keypoints_file(c)) for c in cams}
    clocks, _, _ = motion_clocks(kts, rig, cams[0])
    for c in cams:
        kts[c].frame_times = kts[c].frame_times + SHIFTS.get(c, 0.0)
    shifted, _, _ = motion_clocks(kts, rig, cams[0])
    print("| camera | offset found, synchronised videos (ms) | confidence | shift put in (ms) | recovered (ms) | error (ms) |")
    print("|---|---|---|---|---|---|")
    for c in cams:
        s = SHIFTS.get(c, 0.0)
        rec = shifted[c].offset
        print(f"| {c} | {clocks[c].offset * 1e3:+.2f} | {clocks[c].confidence:.2f} | {-s * 1e3:+.1f} | {rec * 1e3:+.2f} | "
              f"{(rec + s) * 1e3:+.2f} |")


if __name__ == "__main__":
    main()
