"""`mamma-kit fill`: tracks where a view lost a person the other views see -> fill/."""

from __future__ import annotations

from pathlib import Path

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app


@app.command("fill", rich_help_panel="Stages")
def fill_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace with identities.json, keypoints/, masks/, "
                                               "calibration.toml and timing.toml."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Where a person of the capture has no track in a camera but two or more other cameras see
    them, look for them where their skeleton projects (BlazePose, the camera's own tracks blanked)
    and make what is found a track of that person: fill/masks, fill/keypoints, fill/landmarks (the
    new tracks) and fill/identities.json, which fit and report read with the views' own tracks."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.filling.stage import run_fill

    setup(quiet, json_out)
    res = run_fill(Workspace(workspace), force=force)
    if json_out:
        emit_json(res)
