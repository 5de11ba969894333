"""`mamma-kit keypoints`: BlazePose's 33 points for every tracked person -> keypoints/<cam>.npz."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app


@app.command("keypoints", rich_help_panel="Stages")
def keypoints_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace with masks/<cam>.npz (run `track` first)."),
    cameras: Optional[str] = typer.Option(None, "--cameras", help="Comma-separated subset of cameras."),
    blank: bool = typer.Option(True, "--blank/--no-blank", help="Show the model each person alone (the rest of "
                                                                "its input blanked by the track's mask)."),
    resplit: bool = typer.Option(True, "--resplit/--no-resplit", help="Where two people's masks touch, re-split "
                                 "them by the points found and read those people again on their new masks."),
    hands: bool = typer.Option(True, "--hands/--no-hands", help="Read each person's hands too (MediaPipe's hand "
                               "landmarker, 21 points a hand, on the hands BlazePose finds); the fit uses them."),
    threads: Optional[int] = typer.Option(None, "--threads", min=1, help="LiteRT threads (default: up to 2); the results do not depend on it."),
    pictures: bool = typer.Option(True, "--pictures/--no-pictures", help="Write report/keypoints/<cam>.png."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    unit_frames: Optional[int] = typer.Option(None, "--unit-frames", min=0, help="Frames per unit of work "
                                              "(0: a camera per unit; default MAMMA_KIT_UNIT_FRAMES or 0). Each "
                                              "unit starts with the detector, so a split moves the first frames' points."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Per camera, 33 BlazePose points (px), visibility, presence and a score for every (frame, track),
    and each person's hands (21 points a hand with the hand model's flag).

    The person detector, keypoint and hand models (BlazePose GHUM full and MediaPipe's hand landmarker, Apache-2.0) ship with mamma-kit and
    run on the CPU with LiteRT; nothing is downloaded."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.keypoints.stage import run_keypoints

    setup(quiet, json_out)
    res = run_keypoints(Workspace(workspace), cameras=cameras, blank=blank, pictures=pictures, force=force,
                        threads=threads, unit_frames=unit_frames, resplit=resplit, hands=hands)
    if json_out:
        emit_json(res)
