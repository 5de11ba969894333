"""Fit accuracy against ground truth, with landmarks from ground truth plus realistic noise.

    nice -n 10 python benchmarks/fit_accuracy.py [--cache /tmp/mk_fit_bench] [--threads 2]
        [--cases studio,duo] [--counts 2,4,8,16] [--json out.json]

Workspaces are rendered once with `mamma-kit synth` at a quarter of the recipes'
resolution (the fit needs landmarks, not pixels; visibility comes from the renderer) and
cached. Inputs to the fit: the ground-truth calibration and clocks (made relative to the
first camera), and `mamma-kit landmarks --source gt --noise 1.2% --outliers 0.05`: Gaussian
noise of 1.2 % of each person's box height, 5 % of landmarks displaced uniformly within the
box, renderer visibility, sigma = the noise level, contact labels from the scene.

Prints, per case and camera count (cameras chosen by `pick-cameras`, farthest-point
sampling): MPJPE / PA-MPJPE / PVE (mm) after stages 2, 3 and 4 (body / hands split for the
final stage), and for two people the mean penetration depth and penetrating vertices per
frame after stage 3 and stage 4 (and of the ground truth itself).
Paper: 12.96 mm (16 cameras, singles), 17.7 mm (dance); 2/4/8 cameras 24.1/13.7/13.3 mm
(singles) and 47.7/20.2/17.7 mm (dance); contact stage: penetration 10.50 -> 8.46 mm.

    nice -n 10 python benchmarks/fit_accuracy.py --sweep [--sweep-cases duo,studio]
        [--noises 0,0.3%,...] [--outliers 0,0.05] [--clips 30,100] [--json out.json]

--sweep (issue 20: better landmarks must never give a worse fit): landmark noise 0, 0.3,
0.6, 1.2 and 2.4 % of the box height, with 0 and 5 % outliers, on seeds never used to tune
the fit (SWEEP_CASES), each recipe rendered once (100 frames) and fitted on its first 30
frames and on all 100. Prints MPJPE over all joints, body (0-21) and hands (25-54) per
row, then the checks: exact landmarks <= 3 mm (body and hands), MPJPE never more than 10 %
higher at a lower noise (same outliers; body and hands apart), and the 1.2 % / 5 % targets.

    OMP_NUM_THREADS=1 nice -n 15 python benchmarks/fit_accuracy.py --keypoints [--kp-root DIR]
        [--kp-cases duo2718,studio3141] [--kp-frames 30] [--kp-cameras 4]

--keypoints (issue 22): the fit with BlazePose keypoints (`mamma-kit keypoints` on the rendered
videos, people tracked by their true masks) on the captures benchmarks/kp_regressor.py holds out
from the keypoint regressor's learning. Rows per capture: landmarks at 1.2 % noise / 5 %
outliers without and with keypoints (the default weight 0.1 and 1), heavy landmark noise (7 % /
20 % outliers, like a weak network) likewise, keypoints alone (landmarks off), and the network's
own landmarks (the shipped default MammaNet through `mamma-kit landmarks`) without and with keypoints
(`--kp-network-only` runs just those); MPJPE (all, body 0-21) after the last stage, and the keypoints'
share of the stage-2 energy.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CASES = {
    # name: (recipe, scale, frames or None, camera counts, MPJPE target mm)
    "studio": ("studio-16cam-solo", 0.25, 60, (2, 4, 8, 16), 13.0),
    "duo": ("iphone-outdoor-duo", 0.25, 100, (2, 4), 18.0),
}


# --sweep: (recipe, seed never used for tuning, cameras, scale, frames rendered, MPJPE target
# at 1.2 % noise and 5 % outliers). The fit was tuned on iphone-outdoor-duo seed 1618 and tiny.
SWEEP_CASES = {
    "duo": ("iphone-outdoor-duo", 2718, 4, 0.25, 100, 18.0),
    "studio": ("studio-16cam-solo", 3141, 16, 0.25, 100, 13.0),
}
SWEEP_NOISES = ("0", "0.3%", "0.6%", "1.2%", "2.4%")
SWEEP_OUTLIERS = (0.0, 0.05)
SWEEP_CLIPS = (30, 100)
EXACT_MAX_MM = 3.0  # issue 20: exact landmarks, body and hands
MONOTONE_TOL = 0.10  # issue 20: at a lower noise MPJPE may rise by at most 10 %
# a rise below this many mm is evaluation jitter, not a worse fit (exact landmarks end near 0)
MONOTONE_ABS_MM = 0.5


def mk(*args: str) -> None:
    """Run a mamma-kit command in a child process (nice'd, like every long job here)."""
    cmd = ["nice", "-n", "10", sys.executable, "-c", "import sys; from mamma_kit.cli.app import main; main(sys.argv[1:])",
           *map(str, args)]
    subprocess.run(cmd, check=True)


def prepare_workspace(recipe: str, out: Path, scale: float, frames: int | None, noise: str = "1.2%",
                      outliers: float = 0.05, seed: int = 0, synth_seed: int | None = None):
    """A cached synthetic workspace with gt calibration/timing and noisy gt landmarks
    (``seed``: of the landmark noise; ``synth_seed``: of the scene, default the recipe's)."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.fit import install_gt_calibration_and_timing

    if not (out / "gt" / "synth.json").is_file():
        t0 = time.perf_counter()
        args = ["synth", recipe, "--out", out, "--scale", scale, "--no-board", "-q"]
        if frames:
            args += ["--frames", frames]
        if synth_seed is not None:
            args += ["--seed", synth_seed]
        mk(*args)
        print(f"  rendered {recipe} in {time.perf_counter() - t0:.0f} s -> {out}", file=sys.stderr)
    ws = Workspace(out)
    install_gt_calibration_and_timing(ws)
    mk("landmarks", out, "--source", "gt", "--noise", noise, "--outliers", outliers, "--seed", seed, "-q")
    return ws


def fit_and_evaluate(ws, cameras: list[str] | None, stages: int = 4, cfg=None, penetration_frames: int = 40,
                     frames: int | None = None):
    """Fit in-process (keeping each stage's parameters) and evaluate every stage."""
    import torch

    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.smplxfile import SmplxResult
    from mamma_kit.evaluation.fit import evaluate_results
    from mamma_kit.fitting.stages import FitConfig, Fitter
    from mamma_kit.fitting.data import load_fit_data

    model = load_body_model("open")
    data = load_fit_data(ws, camera_list=cameras, n_landmarks=len(model.landmark_ids))
    if frames:
        data = data.slice_frames(slice(0, frames))
    cfg = dataclasses.replace(cfg or FitConfig(), stages=stages)  # the caller's config stays as it was
    w0, c0 = time.perf_counter(), time.process_time()
    res = Fitter(model, data, cfg).fit()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    out = {"cameras": data.cameras, "frames": len(data.frame_times), "people": len(data.person_ids),
           "wall_s": wall, "cpu_s": cpu, "threads": torch.get_num_threads(),
           "stage_seconds": {k: v.to_dict() for k, v in res.stats.items()}, "stages": {}}
    for stage in sorted(res.snapshots):
        results = []
        for i, pid in enumerate(res.person_ids):
            prm = res.params(i, stage)
            from mamma_kit.body.lbs import pose_restricted
            from mamma_kit.fitting.energies import pose_dict

            pose, tr = res.snapshots[stage]
            with torch.no_grad():
                _, J = pose_restricted(model, pose_dict(torch.as_tensor(pose[i:i + 1], dtype=torch.float32),
                                                        torch.as_tensor(tr[i:i + 1], dtype=torch.float32),
                                                        torch.as_tensor(res.betas[i:i + 1], dtype=torch.float32)))
            results.append(SmplxResult.from_params(prm, J[0].numpy(), res.frame_times, res.fps, model.name,
                                                   model.sha256, producer={"reference": data.reference,
                                                                           "person": int(pid)}))
        pen = penetration_frames if len(results) > 1 and stage in ("stage3", "stage4") else 0
        ev = evaluate_results(ws, results, penetration_frames=pen or None) if pen else \
            _no_penetration(ws, results)
        out["stages"][stage] = ev
    return out


def _no_penetration(ws, results):
    from mamma_kit.evaluation.fit import evaluate_results

    one = evaluate_results(ws, results[:1], penetration_frames=None) if len(results) == 1 else None
    if one is not None:
        return one
    # several people but penetration not wanted: evaluate people one by one and average
    per = [evaluate_results(ws, [r], penetration_frames=None) for r in results]
    keys = [k for k, v in per[0].items() if isinstance(v, float)]
    return {k: float(np.mean([p[k] for p in per])) for k in keys}


def sweep(a) -> dict:
    """The noise sweep of --sweep (see module doc); returns the rows and the checks."""
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.fitting.cameras import pick_cameras

    noises = a.noises.split(",") if a.noises else list(SWEEP_NOISES)
    outliers = [float(x) for x in a.outliers.split(",")] if a.outliers else list(SWEEP_OUTLIERS)
    clips = [int(x) for x in a.clips.split(",")] if a.clips else list(SWEEP_CLIPS)
    rows, checks = [], []
    print(f"{'capture':22s} {'seed':>5s} {'cams':>4s} {'frames':>6s} {'noise':>6s} {'outl':>5s} "
          f"{'MPJPE':>7s} {'body':>6s} {'hands':>6s} {'wall s':>7s}")
    for case in a.sweep_cases.split(","):
        recipe, seed, ncam, scale, frames, target = SWEEP_CASES[case]
        root = a.cache / f"sweep_{case}_seed{seed}_s{int(scale * 100):03d}_f{frames}"
        for out in outliers:
            for noise in noises:
                ws = prepare_workspace(recipe, root, scale, frames, noise=noise, outliers=out, synth_seed=seed)
                rig, _ = read_calibration(ws.calibration)
                cams = pick_cameras(rig, min(ncam, len(rig)))
                for clip in clips:
                    r = fit_and_evaluate(ws, cams, frames=clip if clip < frames else None)
                    fin = r["stages"][max(r["stages"])]
                    row = {"case": case, "recipe": recipe, "seed": seed, "cameras": len(cams), "frames": r["frames"],
                           "clip": clip, "noise": noise, "outliers": out, "mpjpe_mm": fin["mpjpe_mm"],
                           "body_mm": fin["mpjpe_body_mm"], "hands_mm": fin["mpjpe_hands_mm"],
                           "wall_s": r["wall_s"], "target_mm": target}
                    rows.append(row)
                    print(f"{recipe:22s} {seed:5d} {len(cams):4d} {r['frames']:6d} {noise:>6s} {out:5.2f} "
                          f"{row['mpjpe_mm']:7.2f} {row['body_mm']:6.2f} {row['hands_mm']:6.2f} "
                          f"{r['wall_s']:7.0f}", flush=True)
    key = lambda r: (r["case"], r["clip"], r["outliers"])  # noqa: E731
    for k in sorted({key(r) for r in rows}):
        grp = sorted((r for r in rows if key(r) == k), key=lambda r: float(r["noise"].rstrip("%")))
        name = f"{k[0]} {k[1]} frames, outliers {k[2]:.2f}"
        for lo, hi in zip(grp, grp[1:]):
            for m in ("body_mm", "hands_mm"):
                ok = lo[m] <= hi[m] * (1 + MONOTONE_TOL) + MONOTONE_ABS_MM
                checks.append({"check": f"{name}: {m[:-3]} at noise {lo['noise']} <= 1.1 x noise {hi['noise']}",
                               "values": [lo[m], hi[m]], "pass": bool(ok)})
        for r in grp:
            if float(r["noise"].rstrip("%")) == 0 and r["outliers"] == 0:
                for m in ("body_mm", "hands_mm"):
                    checks.append({"check": f"{name}: exact landmarks {m[:-3]} <= {EXACT_MAX_MM} mm",
                                   "values": [r[m]], "pass": bool(r[m] <= EXACT_MAX_MM)})
            if r["noise"] == "1.2%" and abs(r["outliers"] - 0.05) < 1e-9:
                checks.append({"check": f"{name}: noise 1.2 % MPJPE <= {r['target_mm']} mm",
                               "values": [r["mpjpe_mm"]], "pass": bool(r["mpjpe_mm"] <= r["target_mm"])})
    for c in checks:
        print(f"{'PASS' if c['pass'] else 'FAIL'}  {c['check']}  ({', '.join(f'{v:.2f}' for v in c['values'])})")
    return {"rows": rows, "checks": checks}


KP_ROWS = (  # (label, landmark noise, outliers, keypoint weight, landmark weight)
    ("landmarks 1.2 %", "1.2%", 0.05, 0.0, 1.0), ("landmarks 1.2 % + keypoints (default 0.1)", "1.2%", 0.05, 0.1, 1.0),
    ("landmarks 1.2 % + keypoints (weight 1)", "1.2%", 0.05, 1.0, 1.0), ("keypoints alone", "1.2%", 0.05, 1.0, 0.0),
    ("landmarks 7 %, 20 % outl.", "7%", 0.2, 0.0, 1.0), ("landmarks 7 %, 20 % outl. + kp (default 0.1)", "7%", 0.2, 0.1, 1.0),
    ("landmarks 7 %, 20 % outl. + kp (weight 1)", "7%", 0.2, 1.0, 1.0),
    # the network's landmarks (`mamma-kit landmarks`, the shipped default weights) on the true masks
    ("network landmarks (embedded-kp)", "net", 0.0, 0.0, 1.0),
    ("network landmarks + keypoints (default 0.1)", "net", 0.0, 0.1, 1.0))


def keypoint_rows(a) -> list[dict]:
    """The --keypoints rows (see module doc)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from kp_regressor import HELDOUT, prepare

    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.evaluation.fit import install_gt_calibration_and_timing
    from mamma_kit.fitting.stages import FitConfig
    from mamma_kit.fitting.cameras import pick_cameras
    from mamma_kit.core.workspace import Workspace

    rows = []
    print(f"{'capture':12s} {'cams':>4s} {'frames':>6s} {'input':40s} {'MPJPE':>7s} {'body':>6s} {'kp share S2':>11s} "
          f"{'wall s':>7s}")
    for case in a.kp_cases.split(","):
        ws = Workspace(prepare(a.kp_root, case, *HELDOUT[case]))
        install_gt_calibration_and_timing(ws)
        rig, _ = read_calibration(ws.calibration)
        cams = pick_cameras(rig, min(a.kp_cameras, len(rig)))
        made = None
        for label, noise, outl, kw, lw in KP_ROWS:
            if a.kp_network_only and noise != "net":
                continue
            if made != (noise, outl):
                if noise == "net":
                    mk("landmarks", ws.root, "--force", "-q")
                else:
                    mk("landmarks", ws.root, "--source", "gt", "--noise", noise, "--outliers", outl, "--seed", 0, "-q")
                made = (noise, outl)
            r = fit_and_evaluate(ws, cams, cfg=FitConfig(keypoint_weight=kw, landmark_weight=lw), frames=a.kp_frames,
                                 penetration_frames=0)
            fin = r["stages"][max(r["stages"])]
            terms = r["stage_seconds"].get("stage2", {}).get("energy_terms", {})
            share = terms.get("keypoints", {}).get("share_end", 0.0)
            row = {"case": case, "input": label, "cameras": len(cams), "frames": r["frames"], "noise": noise,
                   "outliers": outl, "keypoint_weight": kw, "landmark_weight": lw, "mpjpe_mm": fin["mpjpe_mm"],
                   "body_mm": fin["mpjpe_body_mm"], "kp_share_s2": share, "wall_s": r["wall_s"],
                   "energy_terms": {k: v.get("energy_terms") for k, v in r["stage_seconds"].items()}}
            rows.append(row)
            print(f"{case:12s} {len(cams):4d} {r['frames']:6d} {label:40s} {row['mpjpe_mm']:7.1f} {row['body_mm']:6.1f} "
                  f"{share:11.2f} {r['wall_s']:7.0f}", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/mk_fit_bench"))
    ap.add_argument("--cases", default="studio,duo")
    ap.add_argument("--counts", default=None, help="camera counts (default: per case)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--sweep", action="store_true", help="the landmark-noise sweep (see above) instead")
    ap.add_argument("--sweep-cases", default="duo,studio")
    ap.add_argument("--noises", default=None, help="noise levels of --sweep (default 0,0.3%%,0.6%%,1.2%%,2.4%%)")
    ap.add_argument("--outliers", default=None, help="outlier fractions of --sweep (default 0,0.05)")
    ap.add_argument("--clips", default=None, help="clip lengths (frames) of --sweep (default 30,100)")
    ap.add_argument("--keypoints", action="store_true", help="the keypoint rows (see above) instead")
    ap.add_argument("--kp-root", type=Path, default=Path("bench_data/kpreg"),
                    help="benchmarks/kp_regressor.py's --root (captures with keypoints)")
    ap.add_argument("--kp-cases", default="duo2718,studio3141")
    ap.add_argument("--kp-frames", type=int, default=30)
    ap.add_argument("--kp-cameras", type=int, default=4)
    ap.add_argument("--kp-network-only", action="store_true", help="only the rows with the network's landmarks")
    a = ap.parse_args()
    import torch

    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.fitting.cameras import pick_cameras

    torch.set_num_threads(a.threads)
    print(f"# fit accuracy; torch {torch.__version__}, {a.threads} threads, load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    if a.keypoints or a.sweep:
        out = keypoint_rows(a) if a.keypoints else sweep(a)
        print(f"# load average at the end {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
        if a.json:
            a.json.write_text(json.dumps(out, indent=1, default=float))
        return
    report = {}
    for case in a.cases.split(","):
        recipe, scale, frames, counts, target = CASES[case]
        if a.counts:
            counts = tuple(int(c) for c in a.counts.split(","))
        tag = f"{case}_s{int(scale * 100):03d}" + (f"_f{frames}" if frames else "")
        ws = prepare_workspace(recipe, a.cache / tag, scale, frames)
        rig, _ = read_calibration(ws.calibration)
        report[case] = {}
        for k in counts:
            if k > len(rig):
                continue
            cams = pick_cameras(rig, k)
            r = fit_and_evaluate(ws, cams)
            report[case][k] = r
            s = r["stages"]
            fin = s[max(s)]
            line = (f"{recipe:20s} {k:2d} cams {r['frames']:4d} fr  MPJPE S2 {s['stage2']['mpjpe_mm']:6.2f}  "
                    f"S3 {s['stage3']['mpjpe_mm']:6.2f}" + (f"  S4 {s['stage4']['mpjpe_mm']:6.2f}" if 'stage4' in s
                                                             else "") +
                    f"  | final body {fin['mpjpe_body_mm']:5.2f} hands {fin['mpjpe_hands_mm']:5.2f} "
                    f"PA {fin['pa_mpjpe_mm']:5.2f} PVE {fin['pve_mm']:5.2f}  "
                    f"({r['wall_s']:.0f} s wall, {r['cpu_s']:.0f} s cpu)")
            if k == len(rig) or (case == "duo" and k == 4):
                line += f"  target <= {target} mm: {'PASS' if fin['mpjpe_mm'] <= target else 'FAIL'}"
            print(line, flush=True)
            if "penetration" in s.get("stage3", {}) and "stage4" in s:
                p3, p4, pg = s["stage3"]["penetration"], s["stage4"]["penetration"], s["stage4"]["penetration_gt"]
                print(f"{'':20s}    penetration depth mm / vertices per frame: stage 3 {p3['mean_depth_mm']:.2f} / "
                      f"{p3['mean_vertices_per_frame']:.1f}, stage 4 {p4['mean_depth_mm']:.2f} / "
                      f"{p4['mean_vertices_per_frame']:.1f}, ground truth {pg['mean_depth_mm']:.2f} / "
                      f"{pg['mean_vertices_per_frame']:.1f} ({p4['frames']} frames)", flush=True)
    print(f"# load average at the end {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if a.json:
        a.json.write_text(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
