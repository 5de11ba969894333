"""`mamma-kit fit` (the four-stage fit with contact) and `mamma-kit pick-cameras`."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app
from mamma_kit.core import log
from mamma_kit.core.errors import UserError


def parse_stages(text: str) -> int:
    """'1-4' / '4' -> 4 (stages build on each other, so a range starts at 1)."""
    s = str(text).strip()
    try:
        if "-" in s:
            a, b = (int(x) for x in s.split("-", 1))
        else:
            a, b = 1, int(s)
    except ValueError:
        raise UserError(f"--stages '{text}' is not a stage range", "use e.g. --stages 1-4 or --stages 2") from None
    if a != 1:
        raise UserError(f"--stages {text}: every stage starts from the one before it", "use --stages 1-N")
    if not 1 <= b <= 4:
        raise UserError(f"--stages {text}: the fit has stages 1 to 4", "use --stages 1-4, 1-3, 1-2 or 1")
    return b


@app.command("fit", rich_help_panel="Stages")
def fit_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace (calibration.toml, timing.toml, landmarks/)."),
    cameras: Optional[int] = typer.Option(None, "--cameras", help="Use K cameras chosen by farthest-point sampling."),
    camera_list: Optional[str] = typer.Option(None, "--camera-list", help="Use these cameras (comma-separated)."),
    stages: str = typer.Option("1-4", "--stages", help="Stages to run: 1 rigid, 2 pose+shape, 3 uncertainty + "
                                                       "temporal, 4 contact (e.g. 1-3)."),
    body_model: Optional[str] = typer.Option(None, "--body-model", help="'open' or a SMPLX_*.npz file (default: "
                                                                        "capture.toml's, else open)."),
    chunk: int = typer.Option(120, "--chunk", min=8, help="Frames per chunk (chunks overlap by 16 frames)."),
    floor: bool = typer.Option(False, "--floor", help="Stage 4 also keeps feet above the floor (z = 0) and on it "
                                                      "where floor contact is predicted."),
    hands: bool = typer.Option(True, "--hand-points/--no-hand-points", help="Use the hand model's points "
                               "(keypoints/<cam>.npz, where it is sure of a hand) beside the landmarks."),
    view_outliers: float = typer.Option(0.1, "--view-outliers", min=0.0, help="Set a view aside for a frame where "
                                        "its keypoints miss the other views' consensus by more than this fraction of "
                                        "the person's size (0: never; needs 3 or more cameras)."),
    threads: Optional[int] = typer.Option(None, "--threads", min=1, help="CPU threads for torch (default: torch's); the results do not depend on it."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Fit SMPL-X to every matched person in every frame: smplx/person_<k>.npz + smplx/fit_report.json."""
    setup(quiet, json_out)
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.fitting.stage import fit_workspace
    from mamma_kit.fitting.stages import FitConfig

    if cameras is not None and camera_list:
        raise UserError("--cameras and --camera-list both given", "pass one of them")
    n_stages = parse_stages(stages)
    names = [c.strip() for c in camera_list.split(",") if c.strip()] if camera_list else None
    cfg = FitConfig(chunk=chunk, floor=floor, view_outlier_frac=view_outliers)
    if not hands:
        cfg.hand_keypoint_weight = 0.0
    ws = Workspace(workspace)
    rep = fit_workspace(ws, cameras, names, n_stages, body_model, cfg, force=force, threads=threads,
                        command="mamma-kit fit " + " ".join(
                            x for x in [f"--cameras {cameras}" if cameras else "",
                                        f"--camera-list {camera_list}" if camera_list else "",
                                        f"--stages {stages}", "" if hands else "--no-hand-points",
                                        f"--view-outliers {view_outliers:g}"] if x))
    if json_out:
        emit_json(rep)
    elif not rep.get("skipped"):
        rp = rep["reprojection_px"]
        med = ", ".join(f"{c} {v['median']:.2f}" for c, v in rp.items() if v.get("landmarks"))
        log.info(f"fit: {len(rep['persons'])} person(s) x {rep['frames']} frames in {rep['seconds']:.1f} s; "
                 f"median reprojection px: {med}")


@app.command("pick-cameras", rich_help_panel="Tools")
def pick_cameras_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace with calibration.toml."),
    count: int = typer.Option(..., "--count", help="How many cameras to choose."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Choose COUNT cameras spread over positions and viewing directions (farthest-point sampling)."""
    setup(quiet, json_out)
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.fitting.cameras import pick_cameras

    ws = Workspace(workspace)
    if not ws.calibration.is_file():
        raise UserError(f"{ws.root} has no calibration.toml", "run `mamma-kit calibrate WORKSPACE` first")
    rig, _ = read_calibration(ws.calibration)
    names = pick_cameras(rig, count)
    if json_out:
        emit_json({"count": count, "cameras": names, "from": rig.names})
    else:
        typer.echo(",".join(names))
