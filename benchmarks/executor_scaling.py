"""The same units on the local executor and on Ray (1 and 2 workers), the overhead per unit, and
(--costs) what one unit of each stage costs here, for docs/scale.md.

    OMP_NUM_THREADS=1 nice -n 15 .venv/bin/python benchmarks/executor_scaling.py
    OMP_NUM_THREADS=1 nice -n 15 .venv/bin/python benchmarks/executor_scaling.py --costs

Scaling: the track stage's units (builtin backend, one per camera, --force) on a copy of a small
synthetic capture (default /work/bench/kpq/studio_s025_f30_seed103: studio-16cam-solo at 320x240,
about 40 frames per camera, 1 person, its first --cameras 8 cameras; else the tiny recipe is
rendered), run by ``mamma_kit.masks.stage.run_track`` as the command does, on: the local executor with 1 worker (in this process) and 2 (a spawned
pool), and Ray on a local instance (127.0.0.1) with num_cpus 1 and 2. Overhead: N empty units on
each, as wall seconds for 2 units (the fixed cost of a call: a pool's start) and per further unit.
Every run's masks are checked equal to the first's. Ray's own start is timed apart.

Costs: one unit of each stage in a fresh process with one thread (what one worker core does):
wall and CPU seconds, the process's peak RSS, and the sizes of what it reads and writes, per 100
frames of one camera (track, keypoints, landmarks) or of the fit (all people, 4 cameras), and per
board video for detection (default /work/bench/calib/board/cam0.mp4, 1920x1080, detect_fps 10),
on --costs-workspace (default /work/bench/lmq/duo: iphone-outdoor-duo at 960x540, 4 cameras,
about 60 frames, 2 people, with its masks, keypoints and identities).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

DEFAULT_WS = Path("/work/bench/kpq/studio_s025_f30_seed103")
DEFAULT_COSTS_WS = Path("/work/bench/lmq/duo")
DEFAULT_BOARD = Path("/work/bench/calib/board/cam0.mp4")


def _noop(unit):
    return unit


def _load() -> str:
    return ", ".join(f"{x:.1f}" for x in os.getloadavg())


def _workspace(src: Path | None, tmp: Path, cameras: int | None = None) -> Path:
    """A private copy of the capture (the units write into it), with its first ``cameras`` only."""
    ws = tmp / "ws"
    if src is not None and (src / "capture.toml").is_file():
        shutil.copytree(src, ws, ignore=shutil.ignore_patterns(".cache", "report", "smplx"))
        if cameras:
            from mamma_kit.core.io import read_toml, write_toml

            cap = read_toml(ws / "capture.toml")
            cap["cameras"] = dict(list(cap["cameras"].items())[:cameras])
            write_toml(ws / "capture.toml", cap)
    else:
        from mamma_kit.synth.capture import synthesize

        synthesize("tiny", ws, board=False)
    return ws


def _masks(ws: Path) -> dict:
    import numpy as np

    out = {}
    for f in sorted((ws / "masks").glob("*.npz")):
        with np.load(f) as d:
            out.update({f"{f.stem}:{k}": d[k] for k in ("boxes", "rle_counts", "rle_index")})
    return out


def _start_ray(num_cpus: int) -> float:
    import ray

    if ray.is_initialized():
        ray.shutdown()
    t = time.perf_counter()
    ray.init(address="local", num_cpus=num_cpus, include_dashboard=False, logging_level="warning")
    return time.perf_counter() - t


def scaling(a) -> None:
    import numpy as np

    from mamma_kit.core import executor, log
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.masks.stage import run_track

    log.set_quiet(True)
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # before ray's import: 127.0.0.1 only
    tmp = Path(tempfile.mkdtemp(prefix="exec-scaling-"))
    try:
        ws_dir = _workspace(a.workspace, tmp, a.cameras)
        ws = Workspace(ws_dir)
        cams = ws.load_capture().camera_names
        rows, ref = [], None
        configs = [("local", 1), ("local", 2), ("ray", 1), ("ray", 2)]
        for name, workers in configs:
            if name == "ray":
                try:
                    start = _start_ray(workers)
                except ImportError:
                    print("ray is not installed: pip install 'mamma-kit[ray]'")
                    break
            executor.set_executor(name)
            os.environ["MAMMA_KIT_WORKERS"] = str(workers)
            t = time.perf_counter()
            run_track(ws, backend="builtin", pictures=False, force=True)
            track_s = time.perf_counter() - t
            got = _masks(ws_dir)
            if ref is None:
                ref = got
            differ = sorted(set(got) ^ set(ref)) + [k for k in ref if k in got and
                                                     not np.array_equal(got[k], ref[k], equal_nan=True)]
            same = not differ
            if differ:
                print(f"{name} {workers}: masks differ from the first run's: {', '.join(differ[:6])}")
            t = time.perf_counter()
            executor.run_units(_noop, range(2))
            two = time.perf_counter() - t
            t = time.perf_counter()
            executor.run_units(_noop, range(a.noop))
            many = time.perf_counter() - t
            per_unit = (many - two) / (a.noop - 2)
            rows.append((f"{name} {workers} worker{'s' if workers > 1 else ''}", track_s, same, two,
                         per_unit * 1e3, start if name == "ray" else None))
        executor.set_executor(None)
        print(f"units: track --backend builtin, {len(cams)} cameras of {a.workspace or 'tiny'}; "
              f"empty units: {a.noop}; load average after {_load()} on {os.cpu_count()} cores")
        print(f"{'executor':<18} {'track (s)':>10} {'same masks':>11} {'2 empty (s)':>12} "
              f"{'per unit (ms)':>14} {'ray start (s)':>14}")
        for r in rows:
            print(f"{r[0]:<18} {r[1]:>10.1f} {str(r[2]):>11} {r[3]:>12.2f} {r[4]:>14.1f} "
                  f"{'' if r[5] is None else f'{r[5]:.1f}':>14}")
    finally:
        try:
            import ray

            ray.shutdown()
        except ImportError:
            pass
        shutil.rmtree(tmp, ignore_errors=True)


# ---- --costs: one unit of each stage in its own process ---------------------------------
def _one_stage(stage: str, ws_dir: str, board: str | None, q) -> None:
    """Runs in a fresh process: one unit of ``stage``; puts (wall s, cpu s, peak RSS MB, facts)."""
    import resource

    import torch

    torch.set_num_threads(1)
    from mamma_kit.core import log
    from mamma_kit.core.workspace import Workspace

    log.set_quiet(True)
    ws = Workspace(ws_dir)
    cam = ws.load_capture().camera_names[0] if stage != "board" else None
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    c0, t0 = time.process_time(), time.perf_counter()
    facts: dict = {}
    if stage == "board":
        from mamma_kit.calibration.board import load_board_spec
        from mamma_kit.calibration.solve import _detect_unit
        from mamma_kit.calibration.stage import settings_from

        det = _detect_unit(("cam0", Path(board)), load_board_spec("charuco-a1"), settings_from("radtan", 10.0, 40, True),
                           None)
        facts = {"views": len(det.usable(load_board_spec("charuco-a1")))}
    elif stage == "track":
        from mamma_kit.masks.stage import run_track

        run_track(ws, backend="builtin", cameras=[cam], pictures=False, force=True)
    elif stage == "keypoints":
        from mamma_kit.keypoints.stage import run_keypoints

        run_keypoints(ws, cameras=[cam], pictures=False, force=True, threads=1)
    elif stage == "landmarks":
        from mamma_kit.landmarks.stage import run_landmarks

        run_landmarks(ws, cameras=[cam], force=True)
    elif stage == "fit":
        from mamma_kit.fitting.stage import fit_workspace

        rep = fit_workspace(ws, force=True, threads=1)
        facts = {"frames": rep["frames"], "people": len(rep["persons"]), "cameras": len(rep["cameras"])}
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    q.put((wall, cpu, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, rss0, facts, cam))


def _size(paths) -> int:
    return sum(Path(p).stat().st_size for p in paths if Path(p).is_file())


def costs(a) -> None:
    import numpy as np

    tmp = Path(tempfile.mkdtemp(prefix="exec-costs-"))
    ctx = mp.get_context("spawn")
    try:
        ws_dir = _workspace(a.costs_workspace, tmp)
        print(f"workspace: copy of {a.costs_workspace}; board video: {a.board}; load average {_load()} on "
              f"{os.cpu_count()} cores; one thread per unit")
        print(f"{'stage':<10} {'unit':<22} {'wall (s)':>9} {'cpu (s)':>8} {'wall/100 fr (s)':>15} "
              f"{'peak RSS (MB)':>14} {'reads (MB)':>11} {'writes (MB)':>12}")
        # track last: it rewrites masks/<cam>.npz, which keypoints, landmarks and the fit read as given
        stages = ["board", "keypoints", "landmarks", "fit", "track"]
        for stage in stages:
            if stage == "board" and (a.board is None or not Path(a.board).is_file()):
                print(f"{'board':<10} (no board video: --board PATH)")
                continue
            q = ctx.Queue()
            p = ctx.Process(target=_one_stage, args=(stage, str(ws_dir), str(a.board), q))
            p.start()
            wall, cpu, rss, rss0, facts, cam = q.get()
            p.join()
            ws = ws_dir
            if stage == "board":
                from mamma_kit.video import VideoReader

                n = len(VideoReader(a.board).timestamps)
                unit, reads, writes, per100 = f"1 video, {n} frames", _size([a.board]), 0, wall * 100 / n
            elif stage == "fit":
                frames = facts["frames"]
                unit = f"{facts['people']} people x {frames} fr x {facts['cameras']} cams"
                reads = _size(list((ws / "landmarks").glob("*.npz")) + list((ws / "keypoints").glob("*.npz")))
                writes = _size(list((ws / "smplx").glob("*")))
                per100 = wall * 100 / frames
            else:
                with np.load(ws / "masks" / f"{cam}.npz") as d:
                    frames, people = len(d["frame_times"]), len(d["track_ids"])
                video = ws / "videos" / f"{cam}.mp4"
                out = {"track": ws / "masks", "keypoints": ws / "keypoints", "landmarks": ws / "landmarks"}[stage]
                ins = {"track": [video], "keypoints": [video, ws / "masks" / f"{cam}.npz"],
                       "landmarks": [video, ws / "masks" / f"{cam}.npz", ws / "keypoints" / f"{cam}.npz"]}[stage]
                unit = f"{cam}: {frames} fr, {people} people"
                reads, writes, per100 = _size(ins), _size([out / f"{cam}.npz"]), wall * 100 / frames
            print(f"{stage:<10} {unit:<22} {wall:>9.1f} {cpu:>8.1f} {per100:>15.1f} {rss:>14.0f} "
                  f"{reads / 1e6:>11.2f} {writes / 1e6:>12.2f}")
        print("(peak RSS is the whole worker process; after imports, before the unit, it was "
              f"{rss0:.0f} MB in the last one)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workspace", type=Path, default=DEFAULT_WS if DEFAULT_WS.is_dir() else None,
                    help="a capture workspace to copy (default: the 16-camera studio capture, else tiny)")
    ap.add_argument("--cameras", type=int, default=8, help="track units: the workspace's first N cameras")
    ap.add_argument("--costs-workspace", type=Path, default=DEFAULT_COSTS_WS if DEFAULT_COSTS_WS.is_dir() else None,
                    help="workspace for --costs (default: the duo benchmark capture)")
    ap.add_argument("--noop", type=int, default=32, help="empty units for the overhead")
    ap.add_argument("--costs", action="store_true", help="per-unit costs of each stage (docs/scale.md)")
    ap.add_argument("--board", type=Path, default=DEFAULT_BOARD if DEFAULT_BOARD.is_file() else None,
                    help="board video for the detection cost")
    a = ap.parse_args()
    print("command: " + " ".join(sys.argv))
    costs(a) if a.costs else scaling(a)


if __name__ == "__main__":
    main()
