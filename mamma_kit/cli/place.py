"""`mamma-kit place`: the fitted bodies placed in the views that lost them -> place/."""

from __future__ import annotations

from pathlib import Path

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app


@app.command("place", rich_help_panel="Stages")
def place_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace with smplx/ (after `mamma-kit fit`), "
                                               "identities.json, masks/ and calibration.toml."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Where a camera has no track of a fitted person whom two or more other cameras follow, and at
    least a quarter of the body would show in it past the other people (their fitted bodies'
    z-buffer), give that person a track there: the visible silhouette as its mask (place/masks, with
    place/identities.json). People mostly hidden behind others, whom no detector finds, keep their
    identity in every view that shows part of them. Where no other body hides them, BlazePose must
    see a person there (a wall or a door frame hides people the fit knows nothing of); a track with
    no person that already covers the silhouette is named instead. Where two fitted bodies meet in
    a view, a track whose mask is another person's visible silhouette and not its own person's is
    given that person for the frame (a tracker's hand-over at a crossing). The report reads these
    tracks and names; the fit does not (placed tracks carry no keypoints)."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.placing.stage import run_place

    setup(quiet, json_out)
    res = run_place(Workspace(workspace), force=force)
    if json_out:
        emit_json(res)
