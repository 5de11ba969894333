"""mamma-kit calibrate vs aniposelib on the same rendered ChArUco board videos.

Renders a board session for an iPhone-like ring (default: 4 cameras, 1920x1080, fx about
1275 px = an iPhone's main camera at 1080p, 4.5 m from the centre at 1.6 m height, lens
distortion, sensor noise, motion blur, H.264), then calibrates it with

  * mamma-kit (default mode: no clock assumption, still boards matched across cameras),
  * mamma-kit --synced (the videos' timestamps share one clock, as they do here),
  * aniposelib 0.8 (in its own venv, /tmp/aniposelib-venv, created on first use: it pulls
    non-headless OpenCV, jax and numba), which pairs frames by index,

and prints, against the ground truth: focal error (%), principal point (px), camera
rotation (deg) and centre (mm), reprojection RMS (px) and wall time (s). Rotation and
centre are given both directly in the world frame (mamma-kit pins it to the floor board;
aniposelib has no world frame, so N/A) and after a similarity alignment to the truth
(same procedure for every tool).

With --offsets the cameras' videos start at different moments (whole frames apart, as
phones started by hand do): mamma-kit recovers the offsets from the still boards;
aniposelib, pairing frames by index, pairs different moments.

    nice python benchmarks/calib_vs_aniposelib.py --out /tmp/calib-bench
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

VENV = Path("/tmp/aniposelib-venv")

ANIPOSE_SCRIPT = textwrap.dedent('''
    import json, sys, time
    t0 = time.perf_counter()
    from aniposelib.boards import CharucoBoard
    from aniposelib.cameras import CameraGroup
    cfg = json.loads(sys.argv[1])
    board = CharucoBoard(cfg["squares_x"], cfg["squares_y"], square_length=cfg["square_m"],
                         marker_length=cfg["marker_m"], marker_bits=cfg["bits"], dict_size=cfg["dict_size"])
    # aniposelib samples every 20th frame of (typically 30 fps) videos: keep that spacing in time
    import functools
    board.detect_video = functools.partial(board.detect_video, skip=max(1, round(20 * cfg["fps"] / 30)))
    cgroup = CameraGroup.from_names(cfg["names"], fisheye=False)
    error, rows = cgroup.calibrate_videos([[v] for v in cfg["videos"]], board)
    cgroup.dump(cfg["out"])
    print(json.dumps({"error": float(error), "seconds": time.perf_counter() - t0}))
''')


def ensure_venv() -> Path:
    py = VENV / "bin" / "python"
    if not py.exists():
        print(f"creating {VENV} with aniposelib (one time) ...", flush=True)
        subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True)
        subprocess.run([str(VENV / "bin" / "pip"), "install", "-q", "aniposelib"], check=True)
    return py


def ring(n: int, radius: float, height: float, size, f: float, seed: int):
    from mamma_kit.core.camera import Camera, Rig

    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.25
        C = np.array([radius * np.cos(a), radius * np.sin(a), height])
        z = np.array([0.0, 0.0, 0.8]) - C
        z /= np.linalg.norm(z)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        w, h = size
        fi = f * (1 + 0.02 * rng.standard_normal())
        K = np.array([[fi, 0, (w - 1) / 2 + rng.uniform(-15, 15)], [0, fi * (1 + 0.001 * rng.standard_normal()),
                      (h - 1) / 2 + rng.uniform(-15, 15)], [0, 0, 1]])
        dist = [0.10 + 0.03 * rng.standard_normal(), -0.22 + 0.05 * rng.standard_normal(), 0.0004, -0.0003, 0.1]
        cams.append(Camera(f"cam{i}", (w, h), K, dist, "radtan", R, -R @ C))
    return Rig(cams)


def render(out: Path, args) -> None:
    from mamma_kit.calibration.board import load_board_spec
    from mamma_kit.core.calibfile import write_calibration
    from mamma_kit.synth.board import plan_session, render_board_session

    w, h = (int(v) for v in args.size.split("x"))
    rig = ring(args.cams, args.radius, args.height, (w, h), args.f, args.seed)
    spec = load_board_spec(args.board)
    behind = [c for c in (args.behind or "").split(",") if c]
    # with a camera behind the board no floor board is laid (face up, it would show that camera its front)
    traj = plan_session(rig, spec, seed=args.seed, duration_s=args.duration, n_closeups=args.closeups,
                        floor_pose=not behind, behind=behind)
    t0 = time.perf_counter()
    render_board_session(out / "board", rig, spec, seed=args.seed, duration_s=args.duration, fps=args.fps,
                         trajectory=traj, supersample=2, progress=False, workers=None,  # a process per camera
                         floor_pose=not behind, back=args.back, behind=behind)
    write_calibration(out / "gt.toml", rig)
    print(f"rendered {args.cams} x {int(args.duration * args.fps)} frames at {w}x{h} in "
          f"{time.perf_counter() - t0:.0f} s", flush=True)


def shift_videos(src: Path, dst: Path, names: list[str], fps: float, seed: int) -> dict[str, float]:
    """Copies of the videos starting a different whole number of frames late (0-2 s)."""
    from mamma_kit.video import VideoReader, VideoWriter

    rng = np.random.default_rng(seed + 99)
    dst.mkdir(parents=True, exist_ok=True)
    skips = {}
    for i, n in enumerate(names):
        k = 0 if i == 0 else int(rng.integers(3, int(2 * fps)))
        skips[n] = k / fps
        r = VideoReader(src / f"{n}.mp4")
        w, h = r.size
        with VideoWriter(dst / f"{n}.mp4", w, h, fps=fps, crf=16) as wr:
            for j, (t, img) in enumerate(r.frames()):
                if j >= k:
                    wr.write_frame(img, t - k / fps)
    return skips


def run_mamma(videos: list[Path], spec: str, out: Path, extra: list[str]) -> dict:
    cmd = [sys.executable, "-m", "mamma_kit", "calibrate", *map(str, videos), "--board", spec, "--out", str(out),
           "--json", "--quiet", *extra]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if p.returncode != 0:
        return {"failed": p.stderr.strip()[-300:], "seconds": dt}
    return {"summary": json.loads(p.stdout), "seconds": dt}


def run_anipose(videos: list[Path], names: list[str], spec, out: Path, fps: float, rerun: bool = False) -> dict:
    """aniposelib's calibration of the videos (its result is kept and reused unless rerun:
    aniposelib does not change between runs of this script, mamma-kit does)."""
    done = out.with_suffix(".json")
    if not rerun and done.exists() and out.exists():
        return json.loads(done.read_text())
    py = ensure_venv()
    bits = int(spec.dictionary.split("_")[1][0])
    cfg = {"squares_x": spec.squares_x, "squares_y": spec.squares_y, "square_m": spec.square_m,
           "marker_m": spec.marker_m, "bits": bits, "dict_size": int(spec.dictionary.rsplit("_", 1)[1]),
           "names": names, "videos": [str(v) for v in videos], "out": str(out), "fps": fps}
    script = out.with_suffix(".py")
    script.write_text(ANIPOSE_SCRIPT)
    env = dict(os.environ, OMP_NUM_THREADS="2")
    t0 = time.perf_counter()
    p = subprocess.run([str(py), str(script), json.dumps(cfg)], capture_output=True, text=True, env=env)
    dt = time.perf_counter() - t0
    if p.returncode != 0 or not out.exists():
        return {"failed": (p.stderr.strip().splitlines() or ["no output"])[-1][:300], "seconds": dt}
    info = json.loads(p.stdout.strip().splitlines()[-1])
    res = {"error": info["error"], "seconds": dt}
    done.write_text(json.dumps(res))
    return res


def evaluate(path: Path, gt_path: Path, fmt: str | None, pinned: bool) -> dict:
    from mamma_kit.calibration.formats import read_rig
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.evaluation.calibration import compare

    gt, _ = read_calibration(gt_path)
    est = read_rig(path, fmt)
    out = {"aligned": compare(est, gt, align="similarity")["worst"]}
    if pinned:
        out["world"] = compare(est, gt, align="none")["worst"]
    return out


def reprojection_rms(path: Path) -> float | None:
    from mamma_kit.core.calibfile import read_calibration

    _, diag = read_calibration(path)
    return diag["rig"].get("rms_px")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("/tmp/calib-bench"))
    ap.add_argument("--cams", type=int, default=4)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--f", type=float, default=1275.0)
    ap.add_argument("--radius", type=float, default=4.5)
    ap.add_argument("--height", type=float, default=1.6)
    ap.add_argument("--duration", type=float, default=150.0)
    ap.add_argument("--fps", type=float, default=15.0)
    ap.add_argument("--closeups", type=int, default=6)
    ap.add_argument("--board", default="charuco-a1")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--offsets", action="store_true", help="also run on copies starting at different moments")
    ap.add_argument("--no-anipose", action="store_true")
    ap.add_argument("--rerender", action="store_true")
    ap.add_argument("--rerun-anipose", action="store_true", help="recompute aniposelib's result even if present")
    ap.add_argument("--behind", default="", help="cameras (comma-separated) that see the hand-held board only from "
                                                 "behind; no floor board then, and the world frame is not compared")
    ap.add_argument("--back", default="mirror", choices=["plain", "mirror", "see-through"],
                    help="the board's back side with --behind: mirror = printed on both sides")
    args = ap.parse_args()

    from mamma_kit.calibration.board import load_board_spec

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    names = [f"cam{i}" for i in range(args.cams)]
    if args.rerender or not (out / "gt.toml").exists():
        render(out, args)
    spec = load_board_spec(args.board)
    gt = out / "gt.toml"
    videos = [out / "board" / f"{n}.mp4" for n in names]
    rows = []

    def add(tool, res, path, fmt, pinned, rms):
        if "failed" in res:
            rows.append({"tool": tool, "failed": res["failed"], "seconds": res["seconds"]})
            print(f"{tool}: FAILED ({res['failed']})", flush=True)
            return
        ev = evaluate(path, gt, fmt, pinned)
        rows.append({"tool": tool, "seconds": res["seconds"], "rms_px": rms, **ev})
        print(f"{tool}: {json.dumps(rows[-1])}", flush=True)

    floor = ["--no-floor"] if args.behind else []
    pinned = not args.behind  # without a floor board the world frame is the reference camera's
    r = run_mamma(videos, args.board, out / "mamma.toml", ["--no-figures", *floor])
    add("mamma-kit", r, out / "mamma.toml", "mamma-kit", pinned, r.get("summary", {}).get("rms_px"))
    r = run_mamma(videos, args.board, out / "mamma-synced.toml", ["--no-figures", "--synced", *floor])
    add("mamma-kit --synced", r, out / "mamma-synced.toml", "mamma-kit", pinned, r.get("summary", {}).get("rms_px"))
    if not args.no_anipose:
        r = run_anipose(videos, names, spec, out / "anipose.toml", args.fps, args.rerun_anipose)
        add("aniposelib", r, out / "anipose.toml", "anipose", False, r.get("error"))
    if args.offsets:
        if args.rerender or not (out / "board-offsets" / f"{names[-1]}.mp4").exists():
            skips = shift_videos(out / "board", out / "board-offsets", names, args.fps, args.seed)
        else:
            skips = json.loads((out / "offsets.json").read_text())
        (out / "offsets.json").write_text(json.dumps(skips))
        print(f"start offsets (s): {skips}", flush=True)
        sv = [out / "board-offsets" / f"{n}.mp4" for n in names]
        r = run_mamma(sv, args.board, out / "mamma-offsets.toml", ["--no-figures"])
        add("mamma-kit (clock offsets)", r, out / "mamma-offsets.toml", "mamma-kit", True,
            r.get("summary", {}).get("rms_px"))
        if not args.no_anipose:
            r = run_anipose(sv, names, spec, out / "anipose-offsets.toml", args.fps, args.rerun_anipose)
            add("aniposelib (clock offsets)", r, out / "anipose-offsets.toml", "anipose", False, r.get("error"))

    w, h = args.size.split("x")
    print()
    print(f"{args.cams} cameras {w}x{h}, f ~{args.f:.0f} px, ring {args.radius} m at {args.height} m, "
          f"{args.duration:.0f} s at {args.fps:g} fps, board {args.board}; errors: worst camera")
    hdr = ("| tool | focal % | principal point px | rotation deg (world / aligned) | centre mm (world / aligned) "
           "| reprojection rms px | wall s |")
    print(hdr)
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        if "failed" in r:
            print(f"| {r['tool']} | failed: {r['failed'][:80]} | | | | | {r['seconds']:.0f} |")
            continue
        a = r["aligned"]
        wld = r.get("world")
        rot = f"{wld['rotation_deg']:.3f} / {a['rotation_deg']:.3f}" if wld else f"n/a / {a['rotation_deg']:.3f}"
        cen = f"{wld['center_mm']:.1f} / {a['center_mm']:.1f}" if wld else f"n/a / {a['center_mm']:.1f}"
        rms = f"{r['rms_px']:.3f}" if r.get("rms_px") is not None else "?"
        print(f"| {r['tool']} | {a['focal_pct']:.3f} | {a['principal_point_px']:.2f} | {rot} | {cen} | {rms} | "
              f"{r['seconds']:.0f} |")
    (out / "results.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
