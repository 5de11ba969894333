"""`mamma-kit demo --json` twice from empty folders, the second with a CPU hog beside it: the same
figures and the same arrays, for docs/benchmarks.md.

    .venv/bin/python benchmarks/reproducible.py --out /work/bench/repro [--hog 2] [--runs idle,busy]

Each run is the demo command itself in a fresh process (`mamma-kit demo --out OUT/<run> --json
--quiet`): the render, capture-to-smplx and the evaluation. The busy run has ``--hog`` processes
spinning beside it (two take both cores of a two-core machine, as another capture processed
beside it would). Printed: each run's seconds, its load average at the end and its headline
figures; then, against the first run, every array of every stage's output files (masks,
keypoints, landmarks, the timeline, the fitted bodies), every number of calibration.toml and
timing.toml, and the MPJPE to the last digit.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

STAGE_FILES = ("masks", "keypoints", "landmarks", "smplx")


def _spin(stop) -> None:
    while not stop.is_set():
        pass


def demo(out: Path, hog: int) -> dict:
    """One `mamma-kit demo --json` run in a fresh process, with ``hog`` busy processes beside it."""
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    procs = [ctx.Process(target=_spin, args=(stop,), daemon=True) for _ in range(hog)]
    for p in procs:
        p.start()
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, "-m", "mamma_kit", "demo", "--out", str(out), "--json", "--quiet"],
                           capture_output=True, text=True)
    finally:
        load = os.getloadavg()
        stop.set()
        for p in procs:
            p.join(5)
    if r.returncode != 0:
        raise SystemExit(f"demo in {out} failed ({r.returncode}): {r.stderr[-2000:]}")
    res = json.loads(r.stdout)
    (out / "demo.json").write_text(r.stdout)  # the demo's whole summary, beside its workspace
    stages = {k: v["seconds"] for k, v in res["pipeline"]["stages"].items()}
    return {"seconds": time.perf_counter() - t0, "load": load, "headline": res["headline"], "hog": hog,
            "stages": stages, "render": (res.get("synth") or {}).get("seconds")}


def arrays(root: Path) -> dict[str, np.ndarray]:
    out = {}
    files = [f for sub in STAGE_FILES for f in sorted((root / sub).glob("*.npz"))]
    files += [root / "timing_timeline.npz"] if (root / "timing_timeline.npz").is_file() else []
    for f in files:
        with np.load(f, allow_pickle=False) as d:
            for k in d.files:
                if d[k].dtype.kind in "biufc":
                    out[f"{f.relative_to(root)}:{k}"] = d[k]
    return out


def toml_numbers(path: Path) -> dict[str, float]:
    """Every number in a TOML file by its key path, without the run's own record (producer, times)."""
    from mamma_kit.core.io import read_toml

    out: dict[str, float] = {}

    def walk(x, key):
        if isinstance(x, dict):
            for k, v in x.items():
                if k not in ("producer", "seconds", "finished_at"):
                    walk(v, f"{key}.{k}")
        elif isinstance(x, list):
            for i, v in enumerate(x):
                walk(v, f"{key}[{i}]")
        elif isinstance(x, (int, float)) and not isinstance(x, bool):
            out[key] = float(x)

    walk(read_toml(path), path.name)
    return out


def compare(a: Path, b: Path) -> list[tuple[str, int, int, float]]:
    """Per group: (group, values compared, values that differ, largest difference)."""
    rows = []
    xa, xb = arrays(a), arrays(b)
    for group in (*STAGE_FILES, "timing_timeline"):
        keys = [k for k in xa if k.split("/")[0].split(".")[0].split(":")[0] == group]
        n = diff = 0
        worst = 0.0
        for k in keys:
            u, v = xa[k], xb.get(k)
            n += u.size
            if v is None or v.shape != u.shape:
                diff += u.size
                worst = float("inf")
                continue
            same = (u == v) | (np.isnan(u) & np.isnan(v)) if u.dtype.kind in "fc" else (u == v)
            diff += int((~same).sum())
            if u.dtype.kind in "fc" and (~same).any():
                worst = max(worst, float(np.nanmax(np.abs(u - v))))
        rows.append((group, n, diff, worst))
    for name in ("calibration.toml", "timing.toml"):
        ta, tb = toml_numbers(a / name), toml_numbers(b / name)
        d = [abs(ta[k] - tb.get(k, np.inf)) for k in ta if ta[k] != tb.get(k)]
        rows.append((name, len(ta), len(d), max(d) if d else 0.0))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("/work/bench/repro"))
    ap.add_argument("--hog", type=int, default=2, help="busy processes beside the second run")
    ap.add_argument("--runs", default="idle,busy", help="comma-separated run names; the first is idle, the rest busy")
    args = ap.parse_args()
    names = args.runs.split(",")
    res = {}
    for i, name in enumerate(names):
        out = args.out / name
        if out.exists():
            raise SystemExit(f"{out} exists: pass an empty --out")
        res[name] = demo(out, 0 if i == 0 else args.hog)
        h = res[name]["headline"]
        print(f"{name}: {res[name]['seconds']:.0f} s, {res[name]['hog']} busy processes beside it, load average "
              f"{', '.join(f'{x:.1f}' for x in res[name]['load'])}; MPJPE {h['mpjpe_mm']!r} mm, "
              f"PA-MPJPE {h['pa_mpjpe_mm']!r} mm", flush=True)
        print("    render " + (f"{res[name]['render']:.0f} s, " if res[name]["render"] else "") +
              ", ".join(f"{k} {v:.0f} s" for k, v in res[name]["stages"].items()), flush=True)
    ref = names[0]
    for name in names[1:]:
        a, b = res[ref]["headline"], res[name]["headline"]
        print(f"\n{name} against {ref}: MPJPE {b['mpjpe_mm']:.4f} against {a['mpjpe_mm']:.4f} mm "
              f"(difference {abs(b['mpjpe_mm'] - a['mpjpe_mm']):.2g} mm); headline figures "
              f"{'identical' if a == b else 'differ'}")
        print(f"| output | values | differ | largest difference |\n|---|---|---|---|")
        for group, n, diff, worst in compare(args.out / ref, args.out / name):
            print(f"| {group} | {n} | {diff} | {worst:.3g} |")


if __name__ == "__main__":
    main()
