"""`mamma-kit match`: which track in each view shows which person -> identities.json."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.app import app
from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup


@app.command("match")
def match_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace with landmarks/<cam>.npz and calibration.toml."),
    cameras: Optional[str] = typer.Option(None, "--cameras", help="Comma-separated subset of cameras."),
    calibration: Optional[Path] = typer.Option(None, "--calibration", help="calibration.toml to use "
                                                                           "(default: WORKSPACE/calibration.toml)."),
    timing: Optional[Path] = typer.Option(None, "--timing", help="timing.toml to pair frames by time "
                                                                 "(default: WORKSPACE/timing.toml if present)."),
    lam: float = typer.Option(0.05, "--lambda", min=1e-6, help="Affinity temperature, in person heights."),
    max_distance: float = typer.Option(0.12, "--max-distance", min=0.0,
                                       help="Mean epipolar distance (person heights) above which affinity is 0."),
    min_affinity: float = typer.Option(0.25, "--min-affinity", min=0.0, max=1.0,
                                       help="Affinity needed to keep a match or merge groups."),
    plots: bool = typer.Option(True, "--plots/--no-plots", help="Write report/match/affinities.png."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Cross-view identities: tracklet epipolar affinities per camera pair, Hungarian assignment,
    cycle-consistent grouping (no group holds two co-existing tracks of one view)."""
    from mamma_kit.core import log
    from mamma_kit.core.errors import UserError
    from mamma_kit.core.identities import write_identities
    from mamma_kit.core.manifest import StageManifest, producer
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.matching.match import MatchSettings, match_workspace

    setup(quiet, json_out)
    ws = Workspace(workspace)
    cams = [c.strip() for c in cameras.split(",") if c.strip()] if cameras else None
    if cams is None:
        cams = ws.load_capture().camera_names if ws.capture_toml.is_file() else \
            sorted(p.stem for p in ws.landmarks_dir.glob("*.npz"))
    if not cams:
        raise UserError(f"{ws.root} lists no cameras", "check capture.toml or run `mamma-kit landmarks` first")
    calib = calibration or ws.calibration
    tpath = timing or (ws.timing if ws.timing.is_file() else None)
    if timing is not None and not timing.is_file():
        raise UserError(f"timing file not found: {timing}", "run `mamma-kit sync WORKSPACE` or fix --timing")
    settings = MatchSettings(lam=lam, max_distance=max_distance, min_affinity=min_affinity)
    inputs = [ws.landmarks_file(c) for c in cams] + [Path(calib)] + ([Path(tpath)] if tpath else [])
    manifest = StageManifest(ws.cache_dir, "match", ws.root)
    key = {"cameras": cams, "settings": settings.__dict__, "calibration": str(calib), "timing": str(tpath)}
    outputs = [ws.identities]
    state = manifest.check(inputs, key)
    if state.fresh and not force and ws.identities.is_file():
        log.info(f"match: up to date ({state.reason}); skipped (--force recomputes)")
        if json_out:
            emit_json({"stage": "match", "skipped": True, "reason": state.reason})
        return
    t0 = time.perf_counter()
    ident = match_workspace(ws, cams, Path(calib), Path(tpath) if tpath else None, settings)
    hashes = {ws.relative(p): manifest.hasher(p) for p in inputs}
    ident.producer = producer("match " + " ".join(f"{k}={v}" for k, v in settings.__dict__.items()
                                                  if k in ("lam", "max_distance", "min_affinity")), hashes)
    write_identities(ws.identities, ident)
    picture = None
    if plots:
        from mamma_kit.matching.plots import plot_matching

        picture = ws.relative(plot_matching(ident, ws.report_dir / "match" / "affinities.png"))
    secs = time.perf_counter() - t0
    summary = {"stage": "match", "skipped": False, "cameras": cams, "persons": ident.persons(),
               "unassigned": ident.unassigned, "rejected": len(ident.rejected),
               "time_pairing": ident.diagnostics.get("time_pairing"), "picture": picture,
               "identities": ws.relative(ws.identities), "seconds": round(secs, 2)}
    manifest.record(inputs, key, outputs, {k: v for k, v in summary.items() if k != "persons"}, secs)
    if json_out:
        emit_json(summary)
    else:
        for p in ident.persons():
            log.info(f"person {p['id']}: {p['views']} view(s), tracks "
                     + ", ".join(f"{t['camera']}:{t['track']}" for t in p["tracks"]))
        log.info(f"identities.json written ({len(ident.person_ids)} persons, {len(ident.rejected)} rejected "
                 f"matches) in {secs:.1f} s")
