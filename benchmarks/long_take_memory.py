"""Peak memory and time of `mamma-kit match` as a take grows from seconds to minutes.

A rendered capture's stage outputs (landmarks/<cam>.npz, keypoints/<cam>.npz, the true calibration
and clocks; e.g. one that `benchmarks/match_accuracy.py --chain` ran) are played forward and back
(ping-pong, so everyone's motion stays continuous and each track keeps its person) to 1, 4, 16, ...
times their length, written as new workspaces, and `mamma-kit match --no-plots` runs on each in its
own process: its peak resident memory (ru_maxrss of that process) and wall time. The identity
pictures (one video frame per camera) are left out: the looped workspaces have no longer videos.

    nice -n 10 python benchmarks/long_take_memory.py --source /work/bench/ident/room_wander \\
        --out /work/bench/long --loops 1,5,25

With --stages the videos themselves are looped (decoded, played ping-pong, re-encoded; only the
cameras given by --cameras, to keep the run short) and every stage from the videos runs on each
length, each in its own process: `track`, `keypoints`, `landmarks`, `match`, `fill`, `fit` and
`report`, with their peak memory and time, so a stage whose memory grows with the take shows it
(--only: a comma-separated subset, the earlier stages' outputs already there).

    nice -n 10 python benchmarks/long_take_memory.py --source /work/bench/ident/crowd6_seed0 \\
        --out /work/bench/long_stages --stages --cameras cam0,cam4 --loops 1,4,16
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


def make_video_workspace(src: Path, dst: Path, n: int, cams: list[str]) -> tuple[float, int]:
    """dst: src's videos of ``cams`` looped n times (ping-pong), with its true calibration and clocks;
    returns the take's length (s) and frames per camera."""
    import tomli_w

    from mamma_kit.core.workspace import Workspace
    from mamma_kit.video.reader import VideoReader
    from mamma_kit.video.writer import VideoWriter

    ws_src = Workspace(src)
    cap = ws_src.load_capture()
    (dst / "videos").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(ws_src.gt_dir / "calibration.toml", dst / "calibration.toml")
    shutil.copyfile(ws_src.gt_dir / "timing.toml", dst / "timing.toml")
    doc = {"capture": {k: v for k, v in cap.raw.get("capture", {}).items()}, "cameras": {}}
    seconds, frames = 0.0, 0
    for cam in cams:
        entry = cap.cameras[cam]
        rd = VideoReader(entry.video if Path(entry.video).is_absolute() else src / entry.video, entry.rotation)
        imgs = [img for _, img in rd.frames()]
        times = rd.timestamps
        period = float(np.median(np.diff(times))) if len(times) > 1 else 1 / 30
        idx = ping_pong(len(imgs), n)
        h, w = imgs[0].shape[:2]
        with VideoWriter(dst / "videos" / f"{cam}.mp4", w, h, fps=1.0 / period) as wr:
            for i, k in enumerate(idx):
                wr.write_frame(imgs[k], float(times[0] + period * i))
        doc["cameras"][cam] = {"video": f"videos/{cam}.mp4"}
        seconds, frames = max(seconds, period * (len(idx) - 1)), max(frames, len(idx))
    (dst / "capture.toml").write_bytes(tomli_w.dumps(doc).encode())
    return seconds, frames


STAGE_ARGS = {"track": ["--force", "--quiet", "--backend", "pose"], "keypoints": ["--force", "--quiet"],
              "landmarks": ["--force", "--quiet"], "match": ["--force", "--quiet", "--no-plots"],
              "fill": ["--force", "--quiet"], "fit": ["--force", "--quiet"], "report": ["--quiet", "--no-video"]}


def main_stages(args) -> None:
    from stage_process import run_stage

    from mamma_kit.core.identities import read_identities
    from mamma_kit.core.workspace import Workspace

    cams = args.cameras.split(",")
    stages = args.only.split(",") if args.only else list(STAGE_ARGS)
    print(f"{args.source.name}: cameras {', '.join(cams)}; every stage from the videos looped n times "
          f"(peak MB / seconds)")
    print(f"{'n':>4s} {'take s':>8s} {'frames/cam':>10s} {'persons':>7s}  "
          + "  ".join(f"{s:>16s}" for s in stages))
    for n in [int(x) for x in args.loops.split(",")]:
        ws = args.out / f"{args.source.name}_v{n}"
        if (ws / "capture.toml").is_file() and args.only:
            from mamma_kit.core.io import read_npz

            times = read_npz(Workspace(ws).mask_file(cams[0]), keys=("frame_times",))["frame_times"]
            frames, seconds = len(times), float(times[-1] - times[0])
        else:
            seconds, frames = make_video_workspace(args.source, ws, n, cams)
        cells = []
        for stage in stages:
            secs, peak = run_stage([stage, str(ws), *STAGE_ARGS[stage]])
            cells.append(f"{peak:6.0f} / {secs:7.1f}")
        persons = len(read_identities(Workspace(ws).identities).person_ids)
        print(f"{n:4d} {seconds:8.1f} {frames:10d} {persons:7d}  " + "  ".join(f"{c:>18s}" for c in cells),
              flush=True)


def run_match(ws: Path) -> tuple[float, float]:
    from stage_process import run_stage

    return run_stage(["match", str(ws), "--force", "--quiet", "--no-plots"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", type=Path, required=True, help="a rendered workspace with landmarks and keypoints")
    ap.add_argument("--out", type=Path, required=True, help="folder for the looped workspaces")
    ap.add_argument("--loops", default="1,4,16")
    ap.add_argument("--stages", action="store_true", help="loop the videos and run every stage from them")
    ap.add_argument("--cameras", default="cam0,cam4", help="with --stages: the cameras to loop")
    ap.add_argument("--only", default="", help="with --stages: only these stages (comma-separated)")
    args = ap.parse_args()
    if args.stages:
        return main_stages(args)
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
