"""Speed of the synthetic-capture renderer: frames rendered per second, per phase.

    nice -n 10 .venv/bin/python benchmarks/synth_speed.py                # the target case, below
    nice -n 10 .venv/bin/python benchmarks/synth_speed.py --recipe tiny --scale 1 --board

Default case (the issue's target): iphone-outdoor-duo (4 cameras, 2 people, 1920x1080) at
scale 1/3 (640x360), 60 frames, no board session; target: the whole capture in under 60 s
wall clock on 2 cores. It runs ``mamma_kit.synth.capture.synthesize`` as `mamma-kit synth`
does (cameras rendered in parallel worker processes, one per core) and prints the wall time of
its phases (motion, audio, render, board, total: synthesize's own timings) and the CPU time
of this process and its workers together (resource.getrusage; what other jobs on a shared
machine distort least, while wall time also counts waiting for them). CPU time / 2 is about
the wall time on two idle cores.

Each camera records a little before and after the action (its clock offset and a 0.2 s
tail), so it writes more frames than --frames; frames/s counts the frames written (the
requested count is printed too). The load average is printed before and after: compare runs
at similar load.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

TARGET_S = 60.0


def _cpu() -> float:
    """CPU seconds of this process and its finished children (the render workers)."""
    import resource

    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _load() -> str:
    return ", ".join(f"{x:.1f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recipe", default="iphone-outdoor-duo")
    ap.add_argument("--frames", type=int, default=60, help="frames of action per camera (duration = frames / fps)")
    ap.add_argument("--scale", type=float, default=1 / 3, help="fraction of the recipe's resolution (default 1/3)")
    ap.add_argument("--board", action="store_true", help="also render the calibration board session")
    ap.add_argument("--out", type=Path, default=None, help="workspace folder to keep (default: a temp dir, deleted)")
    ap.add_argument("--seed", type=int, default=None)
    a = ap.parse_args()

    print("command: " + " ".join(sys.argv))
    print(f"load average before: {_load()} on {os.cpu_count()} cores; pid {os.getpid()}, "
          f"niceness {os.nice(0)}")
    from mamma_kit.synth.capture import synthesize

    out = a.out or Path(tempfile.mkdtemp(prefix="synth_speed_"))
    try:
        c0, t0 = _cpu(), time.perf_counter()
        res = synthesize(a.recipe, out, seed=a.seed, frames=a.frames, scale=a.scale, board=a.board)
        wall, cpu = time.perf_counter() - t0, _cpu() - c0
        load_after = _load()
        s = res.summary()
        cams = res.cameras
        w, h = cams[0].camera.size
        written = sum(s["frames"].values())
        print(f"recipe {res.recipe.name}: {len(cams)} cameras at {w}x{h} (scale {a.scale:.4g}), "
              f"{res.recipe.people_count} people, seed {res.recipe.seed}, {a.frames} frames requested at "
              f"{res.recipe.fps:g} fps, board {'on' if a.board else 'off'}")
        for ph, secs in res.seconds.items():
            print(f"  {ph:7s} {secs:7.2f} s wall")
        print(f"  CPU     {cpu:7.2f} s (this process and its render workers; CPU/wall {cpu / max(wall, 1e-9):.2f})")
        print(f"frames rendered: {len(cams)} cameras x {a.frames} requested = {len(cams) * a.frames}; "
              f"written {written} ({', '.join(f'{k} {v}' for k, v in s['frames'].items())}: each camera "
              f"also records its clock offset lead and a 0.2 s tail)")
        rw = res.seconds.get("render", wall)
        print(f"render: {written / rw:.2f} frames/s wall; whole capture: {written / wall:.2f} frames/s wall, "
              f"{written / max(cpu, 1e-9):.2f} frames per CPU-second")
        if a.board and "board" in res.seconds:
            from mamma_kit.video.reader import VideoReader

            nb = sum(VideoReader(out / p).n_frames for p in s["paths"]["board_videos"].values())
            print(f"board: {nb} frames in {len(s['paths']['board_videos'])} videos, "
                  f"{nb / res.seconds['board']:.2f} frames/s wall")
        verdict = "PASS" if wall < TARGET_S else "MISS"
        print(f"{verdict}: {wall:.1f} s wall for the whole capture against the {TARGET_S:.0f} s target; "
              f"{cpu:.1f} s CPU, so about {cpu / 2:.0f} s on two idle cores")
        print(f"load average after: {load_after} (other work on the machine slows every wall-clock figure; "
              f"compare runs at similar load)")
    finally:
        if a.out is None:
            shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
