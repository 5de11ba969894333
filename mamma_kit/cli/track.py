"""`mamma-kit track`: person mask tracks per view -> masks/<cam>.npz (+ a picture per camera)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app


@app.command("track", rich_help_panel="Stages")
def track_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace (capture.toml + videos)."),
    backend: str = typer.Option("builtin", "--backend", help="builtin (background model, no weights), pose "
                                                              "(BlazePose, shipped: for real footage), sam2 (needs "
                                                              "--sam2-checkpoint) or gt (synthetic workspaces)."),
    prompts: Optional[Path] = typer.Option(None, "--prompts", help="sam2: TOML with boxes or clicks per person "
                                                                  "(default: builtin detections)."),
    sam2_checkpoint: Optional[Path] = typer.Option(None, "--sam2-checkpoint", help="sam2: checkpoint .pt."),
    sam2_config: Optional[str] = typer.Option(None, "--sam2-config", help="sam2: model config name, e.g. "
                                                                          "configs/sam2.1/sam2.1_hiera_t.yaml."),
    people: Optional[int] = typer.Option(None, "--people", min=1, help="builtin: how many people the capture is "
                                                                     "about, to split blobs of people who touch (default: "
                                                                     "capture.toml \\[capture] people). pose keeps every "
                                                                     "person it follows: match decides who is who."),
    no_plate: bool = typer.Option(False, "--no-plate", help="builtin: background from the capture only, not from "
                                                            "the board videos."),
    chunk: int = typer.Option(64, "--chunk", min=2, help="sam2: frames per chunk (bounds memory)."),
    device: str = typer.Option("cpu", "--device", help="sam2: cpu or cuda."),
    cameras: Optional[str] = typer.Option(None, "--cameras", help="Comma-separated subset of cameras."),
    pictures: bool = typer.Option(True, "--pictures/--no-pictures", help="Write report/tracks/<cam>.png."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Per camera, a mask per person and frame with track ids that stay with the person."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.masks.stage import run_track

    setup(quiet, json_out)
    res = run_track(Workspace(workspace), backend=backend, cameras=cameras, prompts=prompts,
                    sam2_checkpoint=sam2_checkpoint, sam2_config=sam2_config, chunk=chunk, device=device,
                    pictures=pictures, force=force, people=people, plate=not no_plate)
    if json_out:
        emit_json(res)
