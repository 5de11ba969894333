"""Calibration on real recordings: mamma-kit against Caliscope's own calibration.

On each real Caliscope session (../shared/real/caliscope-*: four webcams, a person moving
an inverted ChArUco board, videos/timestamps.csv, Caliscope's camera_array.toml):

1. `mamma-kit calibrate` on the four videos as a new user would run it: the board spec is
   Caliscope's charuco.toml, no --synced (the shared clocks come from timestamps.csv);
2. the board reconstruction residual of a calibration: the board is detected in every
   frame of every camera; for each sync_index (frames taken at one instant), corners seen
   by two or more cameras are triangulated with the calibration (core.camera's
   triangulate_points), the board's known 3D geometry is fitted to them rigidly (Kabsch)
   and the distances left are the residual (mm). Median and p90 over every corner of every
   shared frame with at least 6 such corners, for mamma-kit's calibration and for
   Caliscope's camera_array.toml, on the same frames and the same detections.

    nice -n 15 .venv/bin/python benchmarks/calib_real.py [--json out.json] [--work DIR]

The residual is measured on the frames both calibrations were made from (there is no
held-out board recording): it says how well each calibration explains them in 3D.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "real"
SESSIONS = ("caliscope-charuco_calibration", "caliscope-post_optimization")
MIN_CORNERS = 6


def kabsch(A_n3: np.ndarray, B_n3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising |R A + t - B| (rows are points)."""
    ca, cb = A_n3.mean(0), B_n3.mean(0)
    U, _, Vt = np.linalg.svd((A_n3 - ca).T @ (B_n3 - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cb - R @ ca


def sync_frames(timestamps: Path, names: list[str]) -> dict[int, dict[str, int]]:
    """sync_index -> {camera: frame number} from Caliscope's timestamps.csv (each camera's
    rows in time order are its frames in order)."""
    rows = list(csv.DictReader(open(timestamps, newline="")))
    per: dict[str, list] = {}
    for r in rows:
        per.setdefault(f"cam_{int(r['cam_id'])}", []).append((float(r["frame_time"]), int(r["sync_index"])))
    out: dict[int, dict[str, int]] = {}
    for n in names:
        for k, (_, si) in enumerate(sorted(per[n])):
            out.setdefault(si, {})[n] = k
    return out


def board_residual(rig, dets: dict, frames: dict[int, dict[str, int]], corners_b3: np.ndarray) -> dict:
    """Per-corner rigid-fit residuals (mm) over the shared frames."""
    from mamma_kit.core.camera import triangulate_points

    names = rig.names
    index = {n: {int(f): k for k, f in enumerate(dets[n].index_f)} for n in names}
    res, n_frames = [], 0
    for si, fr in sorted(frames.items()):
        xy = np.full((len(names), len(corners_b3), 2), np.nan)
        for c, n in enumerate(names):
            k = index[n].get(fr.get(n, -1))
            if k is not None:
                xy[c] = dets[n].xy_fn2[k]
        w = np.isfinite(xy[..., 0]).astype(float)
        ok = w.sum(0) >= 2
        if ok.sum() < MIN_CORNERS:
            continue
        X = triangulate_points(rig, xy[:, ok], w[:, ok])
        R, t = kabsch(corners_b3[ok], X)
        res.append(np.linalg.norm(corners_b3[ok] @ R.T + t - X, axis=1) * 1000)
        n_frames += 1
    r = np.concatenate(res) if res else np.zeros(0)
    return {"frames": n_frames, "corners": int(len(r)), "median_mm": float(np.median(r)) if len(r) else None,
            "p90_mm": float(np.percentile(r, 90)) if len(r) else None}


def run_session(folder: Path, work: Path) -> dict:
    from mamma_kit.calibration.board import load_board_spec
    from mamma_kit.calibration.detect import detect_video
    from mamma_kit.calibration.formats import read_rig
    from mamma_kit.calibration.solve import Settings
    from mamma_kit.calibration.stage import calibrate_videos
    from mamma_kit.core.calibfile import read_calibration

    videos = {p.stem: p for p in sorted((folder / "videos").glob("cam_*.mp4"))}
    spec = load_board_spec(folder / "charuco.toml")
    out = work / folder.name / "calibration.toml"
    t0 = time.perf_counter()
    summary = calibrate_videos(videos, str(folder / "charuco.toml"), out, Settings(), report_dir=None,
                               progress=False, cache_dir=work / folder.name / "cache")
    secs = time.perf_counter() - t0
    ours, diag = read_calibration(out)
    theirs = read_rig(folder / "camera_array.toml", "caliscope").subset(ours.names)
    dets = {n: detect_video(p, spec, n, max_fps=None, progress=False) for n, p in videos.items()}
    frames = sync_frames(folder / "videos" / "timestamps.csv", list(videos))
    return {
        "session": folder.name, "cameras": ours.names, "calibrated": len(ours), "seconds": round(secs, 1),
        "timing": diag["rig"].get("timing"), "rms_px": summary["rms_px"],
        "views_from_behind": {n: d.get("frames_seen_from_behind", 0) for n, d in diag["cameras"].items()},
        "rotation_count": {c.name: c.meta.get("rotation_count", 0) for c in theirs},
        "mamma_kit": board_residual(ours, dets, frames, spec.corners_b3),
        "caliscope": board_residual(theirs, dets, frames, spec.corners_b3),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", nargs="*", default=[str(REAL / s) for s in SESSIONS])
    ap.add_argument("--work", default="/tmp/mamma-calib-real")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    rows = []
    for s in a.sessions:
        folder = Path(s)
        if not (folder / "camera_array.toml").is_file():
            print(f"skip {folder}: no camera_array.toml", file=sys.stderr)
            continue
        rows.append(run_session(folder, Path(a.work)))
        r = rows[-1]
        print(f"{r['session']}: {r['calibrated']} cameras calibrated in {r['seconds']} s ({r['timing']}); "
              f"rms {r['rms_px']:.3f} px; board residual over {r['mamma_kit']['frames']} shared frames "
              f"({r['mamma_kit']['corners']} corners): mamma-kit median {r['mamma_kit']['median_mm']:.3f} mm, "
              f"p90 {r['mamma_kit']['p90_mm']:.3f} mm | Caliscope median {r['caliscope']['median_mm']:.3f} mm, "
              f"p90 {r['caliscope']['p90_mm']:.3f} mm")
    print("\n| session | cameras | shared frames | mamma-kit median / p90 (mm) | Caliscope median / p90 (mm) |")
    print("|---|---|---|---|---|")
    for r in rows:
        m, c = r["mamma_kit"], r["caliscope"]
        print(f"| {r['session']} | {r['calibrated']} | {m['frames']} | {m['median_mm']:.3f} / {m['p90_mm']:.3f} | "
              f"{c['median_mm']:.3f} / {c['p90_mm']:.3f} |")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
