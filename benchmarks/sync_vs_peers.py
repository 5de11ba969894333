"""Clap sync accuracy and speed: mamma-kit vs BBC audio-offset-finder vs syncstart.

The same synthetic phone captures (H.264 + AAC files, VFR frames, SNR 10 dB, reverberation,
clock offsets and drift, sound travel) go through `mamma-kit sync` and through both peers,
each installed by this script in its own venv under /tmp (pip; the peers call the ffmpeg
program, so it must be on PATH: `apt-get install ffmpeg`). Errors are those of each camera's
mapping to the reference camera against the true clocks, at the start and the end of the
take; peers give one constant offset, so their error grows with drift.

    nice -n 10 /work/venv/bin/python benchmarks/sync_vs_peers.py [--quick] [--skip-peers]
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import time
import venv
from pathlib import Path

import numpy as np

PEERS = {"audio-offset-finder": ("mk-peer-aof", "audio-offset-finder"), "syncstart": ("mk-peer-syncstart", "syncstart")}


def ensure_peer(name: str) -> Path | None:
    env_name, pkg = PEERS[name]
    env = Path("/tmp") / env_name
    exe = env / "bin" / pkg
    if not exe.exists():
        print(f"# installing {pkg} into {env}", flush=True)
        venv.EnvBuilder(with_pip=True, clear=True).create(env)
        r = subprocess.run([str(env / "bin" / "pip"), "install", "-q", pkg], capture_output=True, text=True)
        if r.returncode != 0 or not exe.exists():
            print(f"# could not install {pkg}: {r.stderr.strip()[-300:]}")
            return None
    return exe


def make_cases(root: Path, quick: bool) -> list[dict]:
    from mamma_kit.core.clock import ClockModel
    from mamma_kit.synth.audio import Ambient, write_sync_workspace

    cases = [
        dict(name="3 cams, 30 s, weak reverb", n_cameras=3, duration_s=30, fps=5, clap_times=[5.0, 24.0],
             reverb="weak", clocks=[ClockModel(0.0, 0.0), ClockModel(1.3721, 60e-6), ClockModel(-2.2113, -90e-6)]),
        dict(name="3 cams, 30 s, strong reverb", n_cameras=3, duration_s=30, fps=5, clap_times=[5.0, 24.0],
             reverb="strong", clocks=[ClockModel(0.0, 0.0), ClockModel(0.8517, 45e-6), ClockModel(-1.5034, 120e-6)]),
        # music from a loudspeaker under the noise: what the peers' whole-track correlation needs
        dict(name="3 cams, 30 s, music + claps, weak reverb", n_cameras=3, duration_s=30, fps=5,
             clap_times=[5.0, 24.0], reverb="weak", ambient=Ambient(),
             clocks=[ClockModel(0.0, 0.0), ClockModel(1.3721, 60e-6), ClockModel(-2.2113, -90e-6)]),
    ]
    if not quick:
        cases += [
            dict(name="2 cams, 5 min, drift 140 ppm", n_cameras=2, duration_s=300, fps=1, clap_times=[10.0, 290.0],
                 reverb="weak", clocks=[ClockModel(0.0, 0.0), ClockModel(0.8, 140e-6)]),
            dict(name="2 cams, 5 min, music + claps, drift 140 ppm", n_cameras=2, duration_s=300, fps=1,
                 clap_times=[10.0, 290.0], reverb="weak", ambient=Ambient(),
                 clocks=[ClockModel(0.0, 0.0), ClockModel(0.8, 140e-6)]),
        ]
    for i, c in enumerate(cases):
        ws = root / f"case{i}"
        if ws.exists():
            shutil.rmtree(ws)
        kw = {k: v for k, v in c.items() if k != "name"}
        info = write_sync_workspace(ws, snr_db=10, seed=100 + i, **kw)
        c.update(ws=ws, info=info)
    return cases


def true_relative(info, n, ref="cam0"):
    t, r = info["clocks"][n], info["clocks"][ref]
    return (t.offset - r.offset) / (1 + r.rate), (1 + t.rate) / (1 + r.rate) - 1


def errors_ms(info, n, offset, rate) -> tuple[float, float]:
    """Mapping error at the camera's first and last frame (ms)."""
    o_t, a_t = true_relative(info, n)
    ts = info["frame_times"][n]
    out = []
    for t in (ts[0], ts[-1]):
        out.append(((1 + rate) * t + offset - ((1 + a_t) * t + o_t)) * 1e3)
    return out[0], out[1]


def run_mamma_kit(case, videos_only: bool = False) -> tuple[dict, float]:
    """The workspace (calibration + clap positions: sound travel corrected), or only the videos
    (as the peers get them: no travel correction)."""
    exe = Path(sys.executable).parent / "mamma-kit"
    target = [str(case["ws"])] if not videos_only else \
        [str(p) for p in case["info"]["videos"].values()] + ["--out", str(case["ws"] / "videos_only.toml")]
    t0 = time.perf_counter()
    r = subprocess.run([str(exe), "sync", *target, "--method", "clap", "--json", "--no-plots", "-q"],
                       capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(r.stderr)
    cams = json.loads(r.stdout)["cameras"]
    return {n: (c["offset_s"], c["rate_ppm"] * 1e-6) for n, c in cams.items()}, dt


def run_aof(exe: Path, ref: Path, cam: Path) -> tuple[float, float]:
    """audio-offset-finder: seconds from the start of `ref` (--within) to the start of `cam`
    (--find-offset-of), negative when cam starts first: ref time = cam time + offset."""
    t0 = time.perf_counter()
    r = subprocess.run([str(exe), "--find-offset-of", str(cam), "--within", str(ref)], capture_output=True, text=True)
    dt = time.perf_counter() - t0
    m = re.search(r"Offset:\s*([-\d.eE]+)", r.stdout)
    if not m:
        raise RuntimeError(f"audio-offset-finder gave no offset: {r.stderr[-300:]}")
    return float(m.group(1)), dt


def run_syncstart(exe: Path, ref: Path, cam: Path, take: float = 20.0) -> tuple[float, float]:
    """syncstart prints (file to cut, seconds): that file's content starts that much earlier."""
    t0 = time.perf_counter()
    r = subprocess.run([str(exe), str(ref), str(cam), "-s", "-q", "-t", str(take)], capture_output=True, text=True)
    dt = time.perf_counter() - t0
    m = None
    for line in r.stdout.splitlines():  # the CSV line: file_to_advance,seconds_to_advance
        m = re.match(r"^(.*\.\w+),\s*([-\d.eE]+)\s*$", line.strip()) or m
    if not m:
        raise RuntimeError(f"syncstart output not understood: {r.stdout!r} {r.stderr[-300:]!r}")
    fname, sec = m.group(1).strip(), float(m.group(2))
    # the named file has `sec` seconds of extra lead: its time t matches the other's t - sec
    if Path(fname).name == cam.name:
        return -sec, dt  # ref time = cam time - sec
    return sec, dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/mk-sync-bench"))
    ap.add_argument("--quick", action="store_true", help="skip the 5-minute take")
    ap.add_argument("--skip-peers", action="store_true")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    peers = {}
    if not args.skip_peers:
        if shutil.which("ffmpeg") is None:
            print("# ffmpeg not on PATH: the peers need it (apt-get install ffmpeg); running mamma-kit only")
        else:
            for name in PEERS:
                exe = ensure_peer(name)
                if exe:
                    peers[name] = exe
    t0 = time.perf_counter()
    cases = make_cases(args.out, args.quick)
    print(f"# wrote {len(cases)} captures in {time.perf_counter() - t0:.1f} s under {args.out}")
    rows = []
    for case in cases:
        for label, vo in (("mamma-kit", False), ("mamma-kit (videos only)", True)):
            est, dt = run_mamma_kit(case, vo)
            names = [n for n in est if n != "cam0"]
            for n in names:
                e0, e1 = errors_ms(case["info"], n, *est[n])
                rows.append((case["name"], n, label, e0, e1, est[n][1] * 1e6, dt / len(names)))
        for pname, exe in peers.items():
            for n in names:
                ref, cam = case["info"]["videos"]["cam0"], case["info"]["videos"][n]
                try:
                    if pname == "audio-offset-finder":
                        off, pdt = run_aof(exe, ref, cam)
                    else:
                        off, pdt = run_syncstart(exe, ref, cam, take=case["duration_s"])
                    e0, e1 = errors_ms(case["info"], n, off, 0.0)
                    rows.append((case["name"], n, pname, e0, e1, 0.0, pdt))
                except RuntimeError as e:
                    rows.append((case["name"], n, pname, float("nan"), float("nan"), 0.0, float("nan")))
                    print(f"# {pname} failed on {case['name']} {n}: {e}")
    print()
    print("| capture | camera | tool | error at start (ms) | error at end (ms) | drift found (ppm) | time per camera (s) |")
    print("|---|---|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:+.4f} | {r[4]:+.4f} | {r[5]:.1f} | {r[6]:.2f} |")
    print()
    tools = list(dict.fromkeys(r[2] for r in rows))
    groups = {"claps only": lambda r: "music" not in r[0], "music + claps": lambda r: "music" in r[0]}
    print("| audio | tool | median error (ms) | worst error (ms) |")
    print("|---|---|---:|---:|")
    med = {}
    for g, sel in groups.items():
        for t in tools:
            errs = [max(abs(r[3]), abs(r[4])) for r in rows if r[2] == t and sel(r)]
            if errs:
                med[(g, t)] = float(np.nanmedian(errs))
                print(f"| {g} | {t} | {med[(g, t)]:.4f} | {np.nanmax(errs):.4f} |")
    print()
    for g in groups:
        for peer in ("audio-offset-finder", "syncstart"):
            if (g, peer) in med and (g, "mamma-kit (videos only)") in med:
                print(f"{g}: median error {peer} / mamma-kit (videos only) = "
                      f"{med[(g, peer)] / med[(g, 'mamma-kit (videos only)')]:.0f}x, "
                      f"/ mamma-kit = {med[(g, peer)] / med[(g, 'mamma-kit')]:.0f}x")


if __name__ == "__main__":
    main()
