"""Faults a user can make, injected into a fitted capture, and what the fit's physical checks say.

    .venv/bin/python benchmarks/fit_faults.py WS --out /tmp/faults [--camera cam1] [--cameras cam0,cam1]

WS is a workspace the chain has fitted (e.g. the demo's). Each case is a copy of it (the videos
linked, not copied) with one fault, fitted again with the same cameras:
- as is: no fault (the checks should flag nothing);
- swapped: one camera's tracks of persons 0 and 1 exchanged in identities.json (a wrong match);
- moved: that camera's centre 0.5 m off in calibration.toml (a bad calibration);
- late: that camera's clock 0.3 s off in timing.toml (a bad sync).
It prints per case whether the checks passed, the impossible / doubtful person-frames by check,
the views the fit set aside (its own defence against a view the others disagree with) and the
median reprojection error.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def copy_workspace(src: Path, dst: Path) -> None:
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("videos", "report", "export", "smplx", ".cache",
                                                            "board", "gt"))
    for name in ("videos", "gt"):  # hard links: the workspace refuses paths that lead outside it
        if (src / name).exists():
            shutil.copytree(src / name, dst / name, copy_function=os.link)


def swap_tracks(ws: Path, cam: str) -> str:
    from mamma_kit.core.io import read_json, write_json

    doc = read_json(ws / "identities.json")
    a = doc["assignments"][cam]
    swap = {0: 1, 1: 0}
    doc["assignments"][cam] = {k: swap.get(v, v) for k, v in a.items()}
    doc["segments"][cam] = [[t, t0, t1, swap.get(p, p)] for t, t0, t1, p in doc.get("segments", {}).get(cam, [])]
    if not doc["segments"][cam]:
        del doc["segments"][cam]
    write_json(ws / "identities.json", doc)
    return f"{cam}'s tracks of persons 0 and 1 swapped"


def move_camera(ws: Path, cam: str, by_m: float = 0.5) -> str:
    import tomllib

    import cv2
    import tomli_w

    doc = tomllib.loads((ws / "calibration.toml").read_text())
    c = doc["cameras"][cam]
    R, t = cv2.Rodrigues(np.asarray(c["rvec"], float))[0], np.asarray(c["t"], float)
    c["t"] = (t - R @ np.array([by_m, 0.0, 0.0])).tolist()  # centre C = -R^T t moved along world x
    (ws / "calibration.toml").write_text(tomli_w.dumps(doc))
    return f"{cam}'s centre {by_m} m off along x"


def late_clock(ws: Path, cam: str, by_s: float = 0.3) -> str:
    import tomllib

    import tomli_w

    doc = tomllib.loads((ws / "timing.toml").read_text())
    doc["cameras"][cam]["offset_s"] = float(doc["cameras"][cam]["offset_s"]) + by_s
    (ws / "timing.toml").write_text(tomli_w.dumps(doc))
    return f"{cam}'s clock {by_s} s off"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("ws", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--camera", default=None, help="the camera to spoil (default: the last one fitted)")
    ap.add_argument("--cameras", default=None, help="fit with these cameras only (comma-separated)")
    ap.add_argument("--cases", default="as-is,swapped,moved,late")
    args = ap.parse_args()

    from mamma_kit.core import log
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.fitting.stage import fit_workspace

    log.set_quiet(True)
    cams = args.cameras.split(",") if args.cameras else Workspace(args.ws).load_capture().camera_names
    cam = args.camera or cams[-1]
    faults = {"as-is": lambda ws: "no fault", "swapped": lambda ws: swap_tracks(ws, cam),
              "moved": lambda ws: move_camera(ws, cam), "late": lambda ws: late_clock(ws, cam)}
    print(f"{args.ws}: fitted with {', '.join(cams)}; faults in {cam}")
    print("| case | fault | checks | impossible person-frames | doubtful | by check | views set aside (person frames) "
          "| median reprojection px |")
    print("|---|---|---|---:|---:|---|---|---|")
    for case in args.cases.split(","):
        dst = args.out / case
        copy_workspace(args.ws, dst)
        what = faults[case](dst)
        rep = fit_workspace(Workspace(dst), camera_list=cams, force=True)
        ch = rep["checks"]
        aside = rep["views_set_aside"]["frames"]
        aside_s = "; ".join(f"{c}: " + ", ".join(f"{p} {n['landmarks']}" for p, n in ps.items())
                            for c, ps in aside.items()) or "none"
        rp = ", ".join(f"{c} {v['median']:.1f}" for c, v in rep["reprojection_px"].items() if "median" in v)
        by = ", ".join(f"{k} {v}" for k, v in ch["by_check"].items()) or "-"
        print(f"| {case} | {what} | {'passed' if ch['passed'] else 'FAILED'} | {ch['impossible_frames']} | "
              f"{ch['doubtful_frames']} | {by} | {aside_s} | {rp} |", flush=True)
        firsts = {}
        for f in ch["flags"]:  # the first flag of each check
            firsts.setdefault(f["check"], f)
        for f in firsts.values():
            print(f"    person {f['person']}, frames {f['frames'][0]}-{f['frames'][1]}: {f['check']}: {f['what']}: "
                  f"{f['cause']}", flush=True)


if __name__ == "__main__":
    main()
