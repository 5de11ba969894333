"""Peak memory and time of `mamma-kit match` as a take grows from seconds to minutes.

A rendered capture's stage outputs (landmarks/<cam>.npz, keypoints/<cam>.npz, the true calibration
and clocks; e.g. one that `benchmarks/match_accuracy.py --chain` ran) are played forward and back
(ping-pong, so everyone's motion stays continuous and each track keeps its person) to 1, 4, 16, ...
times their length, written as new workspaces, and `mamma-kit match --no-plots` runs on each in its
own process: its peak resident memory (ru_maxrss of that process) and wall time. The identity
pictures (one video frame per camera) are left out: the looped workspaces have no longer videos.

    nice -n 10 python benchmarks/long_take_memory.py --source /work/bench/ident/room_wander \\
        --out /work/bench/long --loops 1,5,25
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np


def ping_pong(T: int, n: int) -> np.ndarray:
    """Frame indices of ``n`` times a take of T frames played forward, back, forward, ..."""
    cycle = np.r_[np.arange(T), np.arange(T - 2, 0, -1)] if T > 2 else np.arange(T)
    return np.resize(cycle, n * T)


def looped(tracks, n: int):
    """The same tracks over n times the frames (ping-pong), frame times continued at their period."""
    from dataclasses import fields, replace

    T = len(tracks.frame_times)
    idx = ping_pong(T, n)
    period = float(np.median(np.diff(tracks.frame_times))) if T > 1 else 1.0
    changes = {f.name: getattr(tracks, f.name)[idx] for f in fields(tracks)
               if isinstance(getattr(tracks, f.name), np.ndarray) and getattr(tracks, f.name).ndim >= 2
               and getattr(tracks, f.name).shape[0] == T}
    return replace(tracks, frame_times=tracks.frame_times[0] + period * np.arange(len(idx)), **changes)


def make_workspace(src: Path, dst: Path, n: int) -> tuple[float, int]:
    """dst: src's landmarks and keypoints looped n times; returns the take's length (s) and frames
    per camera (the longest camera's: the cameras' clocks start apart)."""
    from mamma_kit.core.tracks import KeypointTracks, LandmarkTracks
    from mamma_kit.core.workspace import Workspace

    ws_src = Workspace(src)
    dst.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src / "capture.toml", dst / "capture.toml")
    shutil.copyfile(ws_src.gt_dir / "calibration.toml", dst / "calibration.toml")
    shutil.copyfile(ws_src.gt_dir / "timing.toml", dst / "timing.toml")
    ws = Workspace(dst)
    ws.landmarks_dir.mkdir(exist_ok=True)
    ws.keypoints_file("x").parent.mkdir(exist_ok=True)
    seconds, frames = 0.0, 0
    for cam in ws_src.load_capture().camera_names:
        lt = looped(LandmarkTracks.load(ws_src.landmarks_file(cam)), n)
        lt.save(ws.landmarks_file(cam))
        seconds = max(seconds, float(lt.frame_times[-1] - lt.frame_times[0]))
        frames = max(frames, len(lt.frame_times))
        del lt
        if ws_src.keypoints_file(cam).is_file():
            looped(KeypointTracks.load(ws_src.keypoints_file(cam)), n).save(ws.keypoints_file(cam))
    return seconds, frames


def run_match(ws: Path) -> tuple[float, float]:
    from stage_process import run_stage

    return run_stage(["match", str(ws), "--force", "--quiet", "--no-plots"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", type=Path, required=True, help="a rendered workspace with landmarks and keypoints")
    ap.add_argument("--out", type=Path, required=True, help="folder for the looped workspaces")
    ap.add_argument("--loops", default="1,4,16")
    args = ap.parse_args()
    from mamma_kit.core.identities import read_identities
    from mamma_kit.core.workspace import Workspace

    cams = Workspace(args.source).load_capture().camera_names
    print(f"{args.source.name}: {len(cams)} cameras; `mamma-kit match --no-plots` on the take looped n times")
    print(f"{'n':>4s} {'take s':>8s} {'frames/cam':>10s} {'persons':>7s} {'peak MB':>8s} {'seconds':>8s}")
    for n in [int(x) for x in args.loops.split(",")]:
        ws = args.out / f"{args.source.name}_x{n}"
        seconds, frames = make_workspace(args.source, ws, n)
        secs, peak = run_match(ws)
        persons = len(read_identities(Workspace(ws).identities).person_ids)
        print(f"{n:4d} {seconds:8.1f} {frames:10d} {persons:7d} {peak:8.0f} {secs:8.1f}", flush=True)


if __name__ == "__main__":
    main()
