"""`mamma-kit report`: one self-contained HTML page of a capture workspace -> report/index.html."""

from __future__ import annotations

from pathlib import Path

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app


@app.command("report", rich_help_panel="Stages")
def report_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace."),
    no_video: bool = typer.Option(False, "--no-video", help="Skip the short overlay video (stills only)."),
    rerun: bool = typer.Option(False, "--rerun", help="Also write report/recording.rrd for the rerun viewer "
                                                      "(needs `pip install rerun-sdk`)."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Rig, sync, tracks, matching, fit quality, contact, mesh overlays and (synthetic captures)
    ground-truth metrics in one HTML file with every picture and the video embedded."""
    from mamma_kit.core import log
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.report.build import build_report

    setup(quiet, json_out)
    summary = build_report(Workspace(workspace), video=not no_video, rerun=rerun, progress=not quiet)
    if json_out:
        emit_json(summary)
    else:
        for m in summary["missing"]:
            log.info(f"missing {m}")
        log.info(f"{summary['path']}: {len(summary['figures'])} figures, {summary['bytes'] / 1e6:.1f} MB, "
                 f"in {summary['seconds']:.1f} s")
