"""`mamma-kit match`: which track in each view shows which person -> identities.json."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app


@app.command("match", rich_help_panel="Stages")
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
    people: Optional[int] = typer.Option(None, "--people", min=1,
                                         help="Keep the N people the views see best (default: capture.toml \\[capture] "
                                              "people; without: everyone two or more cameras see at once)."),
    window: float = typer.Option(2.0, "--window", min=0.2,
                                 help="Seconds matched at a time; windows are chained by their shared tracks, so a "
                                      "track that jumps from one person to another is split where the views say."),
    plots: bool = typer.Option(True, "--plots/--no-plots", help="Write report/match/affinities.png."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Cross-view identities over the take: per time window, tracklet epipolar affinities per camera
    pair, Hungarian assignment and cycle-consistent grouping; the windows chained by their shared
    tracks; persons seen by one camera only, or beyond --people, set aside with the reason."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.matching.stage import run_match

    setup(quiet, json_out)
    res = run_match(Workspace(workspace), cameras=cameras, calibration=calibration, timing=timing, lam=lam,
                    max_distance=max_distance, min_affinity=min_affinity, people=people, window_s=window, plots=plots, force=force)
    if json_out:
        emit_json(res)
