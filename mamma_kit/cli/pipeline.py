"""`mamma-kit capture-to-smplx` (the whole chain) and `mamma-kit init` (a workspace for your own videos)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app


# init's lists of videos: parsed from the extra arguments, since each takes several values.
VIDEO_LIST_OPTIONS = ("--videos", "--board-videos")


def video_groups(args: list[str]) -> dict[str, list[Path]]:
    """``--videos A B C --board-videos D E F`` (or repeated ``--videos A --videos B``) ->
    {"videos": [...], "board_videos": [...]}; anything else is a user error."""
    from mamma_kit.core.errors import UserError

    groups: dict[str, list[Path]] = {"videos": [], "board_videos": []}
    current = None
    for a in args:
        if a in VIDEO_LIST_OPTIONS:
            current = a[2:].replace("-", "_")
        elif a.startswith("-"):
            raise UserError(f"unknown option {a}", "see `mamma-kit init --help`")
        elif current is None:
            raise UserError(f"unexpected argument {a}", "list the videos after --videos (and --board-videos)")
        else:
            groups[current].append(Path(a))
    if not groups["videos"]:
        raise UserError("no videos given", "pass --videos CAM0.mp4 CAM1.mp4 ... (one per camera)")
    return groups


@app.command("init", rich_help_panel="Your capture",
             context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def init_cmd(
    ctx: typer.Context,
    workspace: Path = typer.Argument(..., help="Folder to create (or fill) as a capture workspace."),
    board: Optional[str] = typer.Option(None, "--board", help="Board spec (built-in name such as charuco-a1, or a "
                                                              "TOML file) the board videos show."),
    names: Optional[str] = typer.Option(None, "--names", help="Comma-separated camera names (default: file stems)."),
    copy: bool = typer.Option(False, "--copy", help="Copy the videos (default: hard links where possible)."),
    backend: str = typer.Option("pose", "--backend", help="Mask backend written to \\[settings.track]: pose (BlazePose, "
                                                          "the best measured on real and synthetic footage), builtin "
                                                          "(background model; needs static cameras and a clean "
                                                          "plate), sam2 or gt."),
    people: Optional[int] = typer.Option(None, "--people", min=1, help="How many people the capture is about "
                                                                       "(match keeps the N the cameras see best and sets aside "
                                                                       "bystanders; without it, everyone two cameras see at once)."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing capture.toml."),
    synced: bool = typer.Option(False, "--synced", help="The cameras share one clock (genlock, a synchronised lab "
                                                        "rig): sync writes identical clocks, no audio needed."),
    calibration: Optional[Path] = typer.Option(None, "--calibration", help="An existing calibration (any format "
                                               "`calib convert` reads, e.g. a Qualisys .qca.txt), written as "
                                               "WORKSPACE/calibration.toml instead of board videos."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Write a capture.toml for your own phone videos:
    `mamma-kit init WORKSPACE --videos A.mov B.mov C.mov [--board-videos A_board.mov B_board.mov C_board.mov
    --board charuco-a1]` (board videos in the same camera order; videos are hard-linked into the workspace)."""
    from mamma_kit.pipeline import init_workspace

    setup(quiet, json_out)
    g = video_groups(list(ctx.args))
    res = init_workspace(workspace, g["videos"], g["board_videos"] or None, board,
                         [n.strip() for n in names.split(",")] if names else None, copy=copy, backend=backend,
                         force=force, people=people, calibration=calibration, synced=synced)
    if json_out:
        emit_json(res)



@app.command("capture-to-smplx", rich_help_panel="Your capture")
def capture_to_smplx_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace (capture.toml; see `mamma-kit init`)."),
    from_stage: Optional[str] = typer.Option(None, "--from", help="First stage to run: calibrate, sync, track, "
                                                                  "keypoints, landmarks, match, fill, fit, place, export or "
                                                                  "report."),
    to_stage: Optional[str] = typer.Option(None, "--to", help="Last stage to run."),
    force: bool = typer.Option(False, "--force", help="Recompute every selected stage even if nothing changed."),
    strict: bool = typer.Option(False, "--strict", help="Exit with code 3 when the fit's physical checks find a "
                                                        "body that cannot be (at or behind a camera, under the "
                                                        "floor, too fast, two persons in one place)."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Calibrate -> sync -> track -> keypoints -> landmarks -> match -> fill -> fit -> place -> export -> report, each
    stage skipped when its inputs are unchanged; an interrupted run resumes where it stopped. The
    export writes export/capture.glb (capture.toml \\[settings.export] formats picks others).

    Stage options come from capture.toml's \\[settings.<stage>] tables."""
    from mamma_kit.pipeline import capture_to_smplx, print_summary

    setup(quiet, json_out)
    summary = capture_to_smplx(workspace, from_stage, to_stage, force=force, progress=not quiet)
    if json_out:
        emit_json(summary)
    else:
        print_summary(summary)
    if strict and not summary.get("checks", {}).get("passed", True):
        raise typer.Exit(3)
