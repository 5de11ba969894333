"""Sync accuracy and speed: mamma-kit's clap sync vs BBC audio-offset-finder vs syncstart, and
mamma-kit's motion and flash sync on rendered captures without audio.

The same synthetic phone captures (H.264 + AAC files, VFR frames, SNR 10 dB, reverberation,
clock offsets and drift, sound travel) go through `mamma-kit sync` and through both peers,
each installed by this script in its own venv under /tmp (pip; the peers call the ffmpeg
program, so it must be on PATH: `apt-get install ffmpeg`). Errors are those of each camera's
mapping to the reference camera against the true clocks, at the start and the end of the
take; peers give one constant offset, so their error grows with drift.

    nice -n 10 /work/venv/bin/python benchmarks/sync_vs_peers.py [--quick] [--skip-peers]
        [--video-only | --audio-only] [--scale 0.3] [--seeds 11 12]

Motion and flash rows: recipes iphone-outdoor-duo and crowd-6 rendered with the audio removed
(no claps, LTC or tmcd), 4 cameras, the recipes' unrelated clock offsets (several frames), drift
(+-25 ppm) and VFR jitter, at 30 and 60 fps, a torch flashed in view (on, then off 0.5 s later;
exposure 0.5-1 frame, rolling-shutter readout 0.3-0.8 frame, per camera). Then, as a user would:
`track --backend pose`, `keypoints`, `sync --method motion` (with the true calibration, so only the
sync is measured), `sync --method flash` and `sync` (auto). The 2-minute drift take renders only
three 3-second windows (start, middle, end; render.windows_s), the frames a line fit through the
windows' offsets needs, at a tenth of the cost of the whole take. --seeds adds the short captures
rendered again with other seeds (other people, motions, placements and clocks), held out from
any tuning.
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


# ---- motion and flash sync on rendered captures without audio ------------------------------
VIDEO_CASES = [
    dict(name="duo, 4 cams, 30 fps", recipe="iphone-outdoor-duo", fps=30.0, duration_s=3.0, flash=[1.2]),
    # leads of 3-18 frames (not the recipe's 0.1-0.9 s): the frames before the action cost rendering
    dict(name="duo, 4 cams, 60 fps", recipe="iphone-outdoor-duo", fps=60.0, duration_s=1.5, flash=[0.6],
         offset_s=[0.05, 0.3]),
    dict(name="crowd-6, 4 cams, 30 fps", recipe="crowd-6", fps=30.0, duration_s=2.5, flash=[1.0], count=4,
         scale=0.45),
    # 2 minutes at 20 fps, rendered in three 3-second windows (start, middle, end)
    dict(name="duo, 4 cams, 20 fps, 2 min (3 windows)", recipe="iphone-outdoor-duo", fps=20.0, duration_s=120.0,
         flash=[1.2, 59.7, 117.7], windows=[[0.0, 3.0], [58.5, 61.5], [117.0, 120.0]]),
]


def video_recipe(case: dict, out: Path, scale: float) -> Path:
    """The case's recipe: the named one with the audio removed, a flash, the case's rate and length."""
    import tomllib

    from mamma_kit.core.io import write_toml
    from mamma_kit.synth.recipe import find_recipe

    r = tomllib.loads(find_recipe(case["recipe"]).read_text())
    fps = case["fps"]
    r["name"] = f"{r['name']}-nosound-{int(fps)}fps"
    r["fps"], r["duration_s"] = fps, case["duration_s"]
    if "count" in case:
        r["rig"]["count"] = case["count"]
    r["rig"]["clock"]["drift_ppm"] = [-25.0, 25.0]
    if "offset_s" in case:
        r["rig"]["clock"]["offset_s"] = case["offset_s"]
    r["audio"] = {"enabled": False}
    r.pop("board", None)
    r["flash"] = {"t": case["flash"], "duration_s": 0.5, "gain": 0.8, "exposure_s": [0.5 / fps, 1.0 / fps],
                  "readout_s": [0.3 / fps, 0.8 / fps]}
    r.setdefault("render", {})["scale"] = case.get("scale", scale)
    if case.get("windows"):
        r["render"]["windows_s"] = case["windows"]
    path = out / f"{r['name']}-{len(case.get('windows') or [])}w.toml"
    write_toml(path, r)
    return path


def run_cli(*args) -> tuple[str, float]:
    exe = Path(sys.executable).parent / "mamma-kit"
    t0 = time.perf_counter()
    r = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"mamma-kit {' '.join(map(str, args))}: {r.stderr.strip()[-600:]}")
    return r.stdout, time.perf_counter() - t0


def make_video_case(case: dict, root: Path, scale: float) -> dict:
    """Render (or reuse) the case's workspace and run track + keypoints on it."""
    ws = root / re.sub(r"[^a-z0-9]+", "-", case["name"].lower()).strip("-")
    seed = ["--seed", case["seed"]] if "seed" in case else []
    secs = {}
    if not (ws / "gt" / "synth.json").is_file():
        root.mkdir(parents=True, exist_ok=True)
        _, secs["render"] = run_cli("synth", video_recipe(case, root, scale), "--out", ws, "--no-board", "-q", *seed)
    shutil.copyfile(ws / "gt" / "calibration.toml", ws / "calibration.toml")
    people = json.loads((ws / "gt" / "synth.json").read_text())["people"]
    _, secs["track"] = run_cli("track", ws, "--backend", "pose", "--people", people, "-q")
    _, secs["keypoints"] = run_cli("keypoints", ws, "-q")
    return dict(case, ws=ws, seconds=secs)


def gt_clocks(ws: Path) -> dict:
    from mamma_kit.core.timingfile import read_timing

    return read_timing(ws / "gt" / "timing.toml")[0]


def video_rows(case: dict) -> list[tuple]:
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.timing.fit import relative_clock
    from mamma_kit.video import VideoReader

    ws = case["ws"]
    gt = gt_clocks(ws)
    rows = []
    # what a user reads from each phone's metadata (or sets): its exposure time
    from mamma_kit.core.io import read_toml, write_toml

    exposures = {n: c["diagnostics"]["exposure_s"] for n, c in read_toml(ws / "gt" / "timing.toml")["cameras"].items()}
    write_toml(ws / "exposure.toml", {"flash": {"exposure_s": exposures}})
    for method, extra in (("motion", []), ("flash", []), ("flash", ["--preset", ws / "exposure.toml"]),
                          ("auto", ["--preset", ws / "exposure.toml"])):
        out = ws / f"timing_{method}{'_exposure' if extra else ''}.toml"
        try:
            _, dt = run_cli("sync", ws, "--method", method, *extra, "--out", out, "--no-plots", "-q")
        except RuntimeError as e:
            print(f"# {case['name']}: {method} failed: {e}")
            continue
        est, meta = read_timing(out)
        for n, c in est.items():
            if n == meta["reference"]:
                continue
            o_t, r_t = relative_clock(gt[n], gt[meta["reference"]])
            ts = VideoReader(ws / "videos" / f"{n}.mp4").timestamps
            e0, e1 = (((1 + c.rate) * t + c.offset - ((1 + r_t) * t + o_t)) * 1e3 for t in (ts[0], ts[-1]))
            label = f"mamma-kit {method}" + (" (exposure given)" if method == "flash" and extra else "") + \
                (f" (chose {meta['method']})" if method == "auto" else "")
            rows.append((case["name"], n, label, e0, e1, c.rate_ppm, (c.rate - r_t) * 1e6, c.confidence, dt))
    return rows


def video_main(args) -> None:
    t0 = time.perf_counter()
    cases = [c for c in VIDEO_CASES if not args.quick or "2 min" not in c["name"]]
    cases += [dict(c, name=f"{c['name']}, seed {seed}", seed=seed) for seed in args.seeds for c in VIDEO_CASES
              if "2 min" not in c["name"]]
    rows = []
    for c in cases:
        done = make_video_case(c, args.out / "video", args.scale)
        print(f"# {c['name']}: " + ", ".join(f"{k} {v:.0f} s" for k, v in done["seconds"].items()), flush=True)
        rows += video_rows(done)
    print(f"# video cases in {time.perf_counter() - t0:.0f} s")
    print()
    print("| capture (no audio) | camera | tool | error at start (ms) | error at end (ms) | drift found (ppm) | "
          "drift error (ppm) | confidence | time (s) |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        drift_err = f"{r[6]:+.1f}" if "2 min" in r[0] else "-"  # short takes: drift not estimated
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:+.3f} | {r[4]:+.3f} | {r[5]:+.1f} | {drift_err} | {r[7]:.2f} | "
              f"{r[8]:.1f} |")
    print()
    print("| method | captures | worst offset error (ms) | median (ms) | worst drift error, 2-min take (ppm) |")
    print("|---|---|---:|---:|---:|")
    for m in ("mamma-kit motion", "mamma-kit flash (exposure given)", "mamma-kit flash", "mamma-kit auto"):
        sel = [r for r in rows if r[2].startswith(m) and (m != "mamma-kit flash" or "given" not in r[2])]
        if not sel:
            continue
        errs = [max(abs(r[3]), abs(r[4])) for r in sel]
        drift = [abs(r[6]) for r in sel if "2 min" in r[0]]
        print(f"| {m} | {len(set(r[0] for r in sel))} | {max(errs):.3f} | {np.median(errs):.3f} | "
              f"{max(drift) if drift else float('nan'):.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/mk-sync-bench"))
    ap.add_argument("--quick", action="store_true", help="skip the 5-minute take")
    ap.add_argument("--skip-peers", action="store_true")
    ap.add_argument("--video-only", action="store_true", help="only the motion and flash rows")
    ap.add_argument("--audio-only", action="store_true", help="only the clap rows and the peers")
    ap.add_argument("--scale", type=float, default=0.3, help="render scale of the motion and flash captures")
    ap.add_argument("--seeds", type=int, nargs="*", default=[],
                    help="also the short motion and flash captures rendered with these seeds")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.audio_only:
        video_main(args)
        if args.video_only:
            return
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
