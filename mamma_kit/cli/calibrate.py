"""`mamma-kit calibrate`: board videos (or a workspace) -> calibration.toml + diagnostics."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app
from mamma_kit.core import log
from mamma_kit.core.errors import UserError


@app.command("calibrate", rich_help_panel="Stages")
def calibrate_cmd(
    targets: List[Path] = typer.Argument(..., help="A workspace folder, or one board video per camera "
                                                   "(camera names = file stems)."),
    board: Optional[str] = typer.Option(None, "--board", "-b", help="Board spec TOML or built-in name "
                                                                    "(workspace: default \\[board] spec)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output calibration.toml (workspace: "
                                                                 "WORKSPACE/calibration.toml)."),
    model: str = typer.Option("radtan", "--model", help="Lens model: radtan (5 coefficients), rational or fisheye."),
    intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="Keep these cameras' intrinsics fixed "
                                                                         "(any calibration format)."),
    timing: Optional[Path] = typer.Option(None, "--timing", help="timing.toml of these board videos: match "
                                                                 "moving-board frames across cameras too."),
    synced: bool = typer.Option(False, "--synced", help="The videos' timestamps share one clock (genlocked "
                                                        "cameras): like --timing with identical clocks."),
    timestamps: Optional[Path] = typer.Option(None, "--timestamps", help="Frame timestamps on one clock (Caliscope "
                                              "timestamps.csv: sync_index, cam_id, frame_time); found beside the "
                                              "videos by itself."),
    report: Optional[Path] = typer.Option(None, "--report", help="Folder for the diagnostic figures (default: "
                                                                 "WORKSPACE/report/calibration or OUT-report/)."),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures."),
    detect_fps: float = typer.Option(10.0, "--detect-fps", help="Frames per second of video searched for the board."),
    max_views: int = typer.Option(40, "--max-views", help="Views per camera used for its intrinsics."),
    no_floor: bool = typer.Option(False, "--no-floor", help="Do not look for the board on the floor."),
    force: bool = typer.Option(False, "--force", help="Workspace: recalibrate even if nothing changed."),
    people: bool = typer.Option(False, "--people", help="Workspace, after `match`: refine the poses of the cameras "
                                "the matched people show to be off, in calibration.toml, from their keypoints (a "
                                "bundle adjustment; the file as it was kept as calibration.before-people.toml); "
                                "then run the stages from `match` again. capture-to-smplx does this itself."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Calibrate a rig from ChArUco board videos: intrinsics, extrinsics, world frame, diagnostics."""
    from mamma_kit.calibration.stage import calibrate_videos, run_calibrate, settings_from

    setup(quiet, json_out)
    settings = settings_from(model, detect_fps, max_views, floor=not no_floor)
    if people:
        from mamma_kit.calibration.people import refine_workspace
        from mamma_kit.core.workspace import Workspace

        if len(targets) != 1 or not targets[0].is_dir():
            raise UserError("--people refines a workspace's calibration", "pass the workspace folder alone")
        res = refine_workspace(Workspace(targets[0]))
        if json_out:
            emit_json(res)
        elif res["refined"]:
            for n in res["refined"]:
                d = res["cameras"][n]
                log.info(f"{n}: moved {100 * d['moved_m']:.1f} cm, turned {d['turned_deg']:.2f} deg; the people's "
                         f"points a median {d['median_px_before']} px -> {d['median_px_after']} px from it")
            log.info(f"{res['output']} refined ({res['before']} holds it as it was): run `mamma-kit capture-to-smplx "
                     f"{targets[0]} --from match`")
        return
    if len(targets) == 1 and targets[0].is_dir():
        from mamma_kit.core.workspace import Workspace

        ws = Workspace(targets[0])
        if out is not None or report is not None:
            raise UserError("--out/--report are for board video files",
                            "a workspace always writes WORKSPACE/calibration.toml and report/calibration/")
        res = run_calibrate(ws, board=board, settings=settings, intrinsics=intrinsics, timing=timing, synced=synced,
                            figures=not no_figures, force=force, progress=not quiet, timestamps=timestamps)
    else:
        videos = {}
        for p in targets:
            if p.is_dir():
                raise UserError(f"{p} is a folder", "pass one workspace folder alone, or board video files")
            if p.stem in videos:
                raise UserError(f"two board videos are named {p.stem}", "camera names come from the file names: "
                                "rename them (e.g. cam0.mp4, cam1.mp4)")
            videos[p.stem] = p
        if board is None:
            raise UserError("no board spec given", "pass --board SPEC (e.g. --board calib/charuco-a1.toml)")
        out = out or Path("calibration.toml")
        report = report or out.with_name(out.stem + "-report")
        res = calibrate_videos(videos, board, out, settings, report_dir=None if no_figures else report,
                               intrinsics=intrinsics, timing=timing, synced=synced, progress=not quiet,
                               command="calibrate " + " ".join(str(t) for t in targets), timestamps=timestamps)
    if json_out:
        emit_json(res)
    elif not res.get("skipped"):
        log.info(f"{res['output']}: {len(res['cameras'])} cameras, bundle-adjusted rms {res['rms_px']:.3f} px over "
                 f"{res['events']['total']} board poses ({res['events']['shared']} shared); world from "
                 f"{res['world']['source']}; clocks: {res.get('timing', '?')}")
        for n, cd in res["cameras"].items():
            cv = (cd.get("cross_validation_px") or {}).get("median_px")
            behind = f", {cd['frames_seen_from_behind']} frames seen from behind" \
                if cd.get("frames_seen_from_behind") else ""
            log.info(f"  {n}: rms {cd['rms_px']:.3f} px, fx {cd['fx']:.1f} px, {cd['views']} views "
                     f"({cd['shared_views']} shared){behind}" + (f", cross-validation {cv:.2f} px" if cv is not None
                                                                 else ""))
        if res.get("figures"):
            log.info(f"figures: {Path(res['figures'][0]).parent}")
