"""`mamma-kit demo`: the whole chain on a small synthetic capture, with its evaluation.

Renders (once) an iphone-outdoor-duo capture - four phone-like cameras, two people dancing
hand in hand, a ChArUco board session, claps and LTC, unsynchronised drifting clocks - then
runs capture-to-smplx on it exactly as on a real capture (the ground truth in gt/ is only
read afterwards, by eval) and prints the errors against the ground truth and the report path.
"""

from __future__ import annotations

import time
from pathlib import Path

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app
from mamma_kit.core import log

DEMO_RECIPE = "iphone-outdoor-duo"


def _synth_once(out: Path, frames: int, scale: float, seed: int | None) -> dict:
    """Render the capture unless ``out`` already holds this very one."""
    from mamma_kit.core.io import read_json, write_json
    from mamma_kit.synth.capture import synthesize

    # (None left out: the JSON writer drops nulls, and the stored key must compare equal)
    key = {k: v for k, v in {"recipe": DEMO_RECIPE, "frames": frames, "scale": scale, "seed": seed}.items()
           if v is not None}
    stamp = out / ".cache" / "demo-synth.json"
    if stamp.is_file() and (out / "capture.toml").is_file():
        try:
            if read_json(stamp).get("key") == key:
                log.info(f"demo capture already rendered in {out}: reusing it")
                return {"skipped": True, **key}
        except Exception:
            pass
    log.info(f"rendering the demo capture ({DEMO_RECIPE}, {frames} frames at {scale:g} x 1920x1080, 4 cameras, "
             "board session, claps + LTC)")
    t0 = time.perf_counter()
    res = synthesize(DEMO_RECIPE, out, seed=seed, frames=frames, scale=scale)
    write_json(stamp, {"key": key})
    return {"skipped": False, "seconds": round(time.perf_counter() - t0, 1), **key, "phases": res.seconds}


def headline(ev: dict) -> dict:
    """The figures a reader looks for first, from `mamma-kit eval`'s groups."""
    out: dict = {}
    fit = ev.get("fit") or {}
    if fit:
        out["mpjpe_mm"] = fit.get("mpjpe_mm")
        out["pa_mpjpe_mm"] = fit.get("pa_mpjpe_mm")
        out["pve_mm"] = fit.get("pve_mm")
    calg = ev.get("calibration") or {}
    # the rig after a similarity onto the truth: where the board lay on the floor fixes the
    # world's yaw and origin, which no calibration can know; the floor's tilt it can
    cal = (calg.get("relative") or {}).get("worst") or calg.get("worst") or {}
    if cal:
        out["calibration_worst"] = {k: cal.get(k) for k in ("rotation_deg", "center_mm", "focal_pct")}
    if calg.get("world_frame"):
        out["floor_tilt_deg"] = calg["world_frame"].get("tilt_deg")
    tim = ev.get("timing") or {}
    if tim:
        out["sync_worst_offset_error_ms"] = tim.get("worst_offset_error_ms")
    ids = ev.get("identities") or {}
    if ids:
        out["identity_accuracy"] = ids.get("accuracy")
    lm = ev.get("landmarks") or {}
    if lm:
        out["landmark_error_pct_box_visible"] = lm.get("error_pct_box_visible")
    return out


@app.command(rich_help_panel="Your capture")
def demo(
    out: Path = typer.Option(Path("demo-out"), "--out", help="Folder for the demo capture and its results."),
    frames: int = typer.Option(60, "--frames", min=8, help="Frames per camera (30 fps)."),
    scale: float = typer.Option(0.5, "--scale", min=0.1, max=1.0, help="Resolution as a fraction of 1920x1080."),
    seed: int = typer.Option(None, "--seed", help="Recipe seed (default: the recipe's)."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Render a small two-person capture, run capture-to-smplx on it and evaluate it against
    its ground truth: MPJPE and the report path at the end."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.stage import evaluate_workspace
    from mamma_kit.pipeline import capture_to_smplx, print_summary

    setup(quiet, json_out)
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    synth = _synth_once(out, frames, scale, seed)
    run = capture_to_smplx(out, progress=not quiet)
    print_summary(run)
    ev = evaluate_workspace(Workspace(out))
    report = run["stages"].get("report", {}).get("summary", {}).get("path")
    summary = {"workspace": str(out.resolve()), "synth": synth, "pipeline": run, "eval": ev,
               "headline": headline(ev), "report": report, "seconds": round(time.perf_counter() - t0, 1)}
    if json_out:
        emit_json(summary)
    else:
        h = summary["headline"]
        for k, v in h.items():
            log.info(f"{k}: {v}")
        log.info(f"report: {report}")
        log.info(f"demo finished in {summary['seconds']:.0f} s")
