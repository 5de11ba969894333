"""Speed of the whole chain to the fit on the real two-person recording, against the decode floor.

Input: ../shared/real/pose2sim-multiperson (four cameras, 1088x1920 portrait H.264, 100 frames each,
two people), `init --calibration --synced --people 2` in ROOT/ws. Each stage runs as a user runs it,
`mamma-kit STAGE WS --force` in its own process (track with the pose backend, keypoints, landmarks,
match, fit), timed with its peak resident memory. The decode floor is what merely decoding the same
four videos to RGB frames as displayed costs (PyAV through mamma_kit.video.VideoReader), measured in
the same run, before and after the stages (the smaller counts: a shared machine only slows a run).

Printed per stage: seconds, peak MB, person-view-frames per second (a matched person in a camera
in a frame: the present (frame, track) cells of the tracks `match` gave a person), and the stage's
time over the decode floor; then the chain end to end. The issue's targets: >= 24 person-view-frames/s end to end, <= 25x the decode floor.

    .venv/bin/python benchmarks/speed_real.py --root /tmp/speed [--profile | --only-profile]

With --profile each stage runs once more under cProfile and its ten most expensive functions (own
time) are printed: where each stage's time goes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

STAGES = [("track", ["--backend", "pose", "--people", "2"]), ("keypoints", []), ("landmarks", []), ("match", []),
          ("fill", []), ("fit", [])]


def decode_floor(videos: list[Path]) -> tuple[float, int]:
    """Seconds to decode every frame of the videos to RGB as displayed, and the frames decoded."""
    from mamma_kit.video import VideoReader

    t0, n = time.perf_counter(), 0
    for v in videos:
        for _t, _rgb in VideoReader(v).frames():
            n += 1
    return time.perf_counter() - t0, n


def person_view_frames(ws) -> tuple[int, int]:
    """(frame, track) cells of the tracks `match` gave a person (the people fitted: bystanders and
    duplicates left out), and of every track kept by the tracker."""
    from mamma_kit.core.identities import read_identities
    from mamma_kit.core.tracks import MaskTracks

    ident = read_identities(ws.identities)
    matched = tracked = 0
    for c in ws.load_capture().camera_names:
        mt = MaskTracks.load(ws.mask_file(c))
        mine = np.array([ident.person_of(c, t) is not None for t in mt.track_ids], bool)
        matched += int(mt.present[:, mine].sum())
        tracked += int(mt.present.sum())
    return matched, tracked


def profile_stage(stage: str, args: list[str], out: Path, top: int = 10) -> None:
    """The stage under cProfile in its own process; its most expensive functions by own time."""
    import os
    import pstats
    import subprocess

    # units in this process (not a spawned pool), so that the profile sees their work
    subprocess.run([sys.executable, "-m", "cProfile", "-o", str(out), "-m", "mamma_kit", stage, *args], check=True,
                   capture_output=True, env={**os.environ, "MAMMA_KIT_WORKERS": "1"})
    st = pstats.Stats(str(out))
    total = st.total_tt
    print(f"  {stage}: {total:.1f} s profiled; own time of the top {top} functions")
    rows = sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:top]
    for (file, line, name), (_cc, ncalls, tt, ct, _callers) in rows:
        where = f"{Path(file).parent.name}/{Path(file).name}:{line}" if file != "~" else "builtin"
        print(f"    {100 * tt / total:5.1f} %  {tt:7.2f} s own  {ct:7.2f} s cumulative  {ncalls:8d} calls  {name}  ({where})")


def profile_all(ws, root: Path) -> None:
    for stage, extra in STAGES:
        profile_stage(stage, [str(ws.root), "--force", "--quiet", *extra], root / f"{stage}.prof")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("bench_data/speed"))
    ap.add_argument("--profile", action="store_true", help="also profile each stage (a second run)")
    ap.add_argument("--only-profile", action="store_true", help="profile the stages of a workspace made before")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    from real_workspace import real_workspace
    from stage_process import run_stage

    ws = real_workspace(args.root)
    videos = [ws.root / ws.load_capture().cameras[c].video for c in ws.load_capture().camera_names]
    if args.only_profile:
        profile_all(ws, args.root)
        return
    floor_s, n_frames = decode_floor(videos)
    rows = {}
    for stage, extra in STAGES:
        rows[stage] = run_stage([stage, str(ws.root), "--force", "--quiet", *extra])
    floor_s = min(floor_s, decode_floor(videos)[0])
    pvf, tracked = person_view_frames(ws)
    print(f"{len(videos)} videos, {n_frames} frames; decode floor {floor_s:.2f} s; {pvf} person-view-frames "
          f"of the persons matched ({tracked} of every track kept)")
    print(f"{'stage':10s} {'seconds':>8s} {'peak MB':>8s} {'pvf/s':>8s} {'x floor':>8s}")
    for stage, (secs, mb) in rows.items():
        print(f"{stage:10s} {secs:8.1f} {mb:8.0f} {pvf / secs:8.1f} {secs / floor_s:8.1f}")
    total = sum(s for s, _ in rows.values())
    print(f"{'end to end':10s} {total:8.1f} {max(m for _, m in rows.values()):8.0f} {pvf / total:8.1f} "
          f"{total / floor_s:8.1f}   (targets: >= 24 pvf/s, <= 25x the floor)")
    if args.json:
        args.json.write_text(json.dumps({"floor_s": floor_s, "frames": n_frames, "person_view_frames": pvf,
                                         "tracked_view_frames": tracked,
                                         "stages": rows}, indent=1))
    if args.profile:
        print("profiles (each stage once more, under cProfile):")
        profile_all(ws, args.root)


if __name__ == "__main__":
    main()
