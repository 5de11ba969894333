"""`mamma-kit calibrate`: board videos (or a workspace) -> calibration.toml + diagnostics."""

from __future__ import annotations

import time
from pathlib import Path
from typing import List, Optional

import typer

from mamma_kit.cli.app import app
from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.core import log
from mamma_kit.core.errors import UserError


@app.command("calibrate")
def calibrate_cmd(
    targets: List[Path] = typer.Argument(..., help="A workspace folder, or one board video per camera "
                                                   "(camera names = file stems)."),
    board: Optional[str] = typer.Option(None, "--board", "-b", help="Board spec TOML or built-in name "
                                                                    "(workspace: default [board] spec)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output calibration.toml (workspace: "
                                                                 "WORKSPACE/calibration.toml)."),
    model: str = typer.Option("radtan", "--model", help="Lens model: radtan (5 coefficients), rational or fisheye."),
    intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="Keep these cameras' intrinsics fixed "
                                                                         "(any calibration format)."),
    timing: Optional[Path] = typer.Option(None, "--timing", help="timing.toml of these board videos: match "
                                                                 "moving-board frames across cameras too."),
    synced: bool = typer.Option(False, "--synced", help="The videos' timestamps share one clock (genlocked "
                                                        "cameras): like --timing with identical clocks."),
    report: Optional[Path] = typer.Option(None, "--report", help="Folder for the diagnostic figures (default: "
                                                                 "WORKSPACE/report/calibration or OUT-report/)."),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures."),
    detect_fps: float = typer.Option(10.0, "--detect-fps", help="Frames per second of video searched for the board."),
    max_views: int = typer.Option(40, "--max-views", help="Views per camera used for its intrinsics."),
    no_floor: bool = typer.Option(False, "--no-floor", help="Do not look for the board on the floor."),
    force: bool = typer.Option(False, "--force", help="Workspace: recalibrate even if nothing changed."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Calibrate a rig from ChArUco board videos: intrinsics, extrinsics, world frame, diagnostics."""
    from mamma_kit.calibration.board import load_board_spec
    from mamma_kit.calibration.solve import Settings, calibrate, summary, write_outputs
    from mamma_kit.core.clock import ClockModel
    from mamma_kit.core.manifest import StageManifest, producer

    setup(quiet, json_out)
    if model not in ("radtan", "rational", "fisheye"):
        raise UserError(f"unknown lens model '{model}'", "use --model radtan, rational or fisheye")
    ws = None
    if len(targets) == 1 and targets[0].is_dir():
        from mamma_kit.core.workspace import Workspace

        ws = Workspace(targets[0])
        cap = ws.load_capture()
        videos = {n: e.board_video for n, e in cap.cameras.items() if e.board_video is not None}
        if not videos:
            raise UserError("capture.toml names no board videos", "add board_video = \"board/NAME.mp4\" to each "
                            "[cameras.NAME], or pass the board videos themselves")
        missing = [n for n in cap.cameras if n not in videos]
        if missing:
            raise UserError(f"capture.toml has no board_video for {', '.join(missing)}",
                            "add board_video to those cameras or leave them out of capture.toml")
        spec_src = board or (str(cap.board_spec) if cap.board_spec else None)
        if spec_src is None:
            raise UserError("no board spec: capture.toml has no [board] spec", "pass --board SPEC or add "
                            "[board] spec = \"charuco.toml\" to capture.toml")
        out = out or ws.calibration
        report = report or ws.report_dir / "calibration"
    else:
        for p in targets:
            if p.is_dir():
                raise UserError(f"{p} is a folder", "pass one workspace folder alone, or board video files")
        videos = {}
        for p in targets:
            if p.stem in videos:
                raise UserError(f"two board videos are named {p.stem}", "camera names come from the file names: "
                                "rename them (e.g. cam0.mp4, cam1.mp4)")
            videos[p.stem] = p
        if board is None:
            raise UserError("no board spec given", "pass --board SPEC (e.g. --board calib/charuco-a1.toml)")
        spec_src = board
        out = out or Path("calibration.toml")
        report = report or out.with_name(out.stem + "-report")
    for n, p in videos.items():
        if not Path(p).is_file():
            raise UserError(f"board video of {n} not found: {p}", "check the path")
    spec = load_board_spec(spec_src)
    settings = Settings(model=model, max_fps=detect_fps, max_views=max_views, floor=not no_floor)
    rig_intr = None
    if intrinsics is not None:
        from mamma_kit.calibration.formats import read_rig

        rig_intr = read_rig(intrinsics)
    clocks = None
    if timing is not None:
        from mamma_kit.core.timingfile import read_timing

        clocks, _ = read_timing(timing)
    elif synced:
        clocks = {n: ClockModel(source="synced") for n in videos}
    inputs = [Path(p) for p in videos.values()] + [Path(spec_src) if Path(spec_src).is_file() else Path()]
    inputs += [p for p in (intrinsics, timing) if p is not None]
    inputs = [p for p in inputs if str(p) not in ("", ".")]
    run_settings = {**settings.to_dict(), "spec": spec.to_dict(), "synced": synced, "figures": not no_figures}
    manifest = StageManifest(ws.cache_dir, "calibrate", ws.root) if ws is not None else None
    if manifest is not None and not force and out == ws.calibration:
        state = manifest.check(inputs, run_settings)
        if state.fresh:
            from mamma_kit.core.calibfile import read_calibration

            log.info(f"calibration is up to date ({state.reason}); use --force to recalibrate")
            if json_out:
                rig, diag = read_calibration(out)
                emit_json({"rms_px": diag["rig"].get("rms_px"), "skipped": True, "output": str(out),
                           "cameras": {n: {"rms_px": d.get("rms_px")} for n, d in diag["cameras"].items()}})
            return
    t0 = time.perf_counter()
    result = calibrate({n: Path(p) for n, p in videos.items()}, spec, settings, intrinsics=rig_intr,
                       intrinsics_src=str(intrinsics), clocks=clocks, progress=not quiet,
                       cache_dir=ws.cache_dir / "board-detections" if ws is not None else None)
    if manifest is not None:
        hashes = {str(p): manifest.hasher(p) for p in inputs}
        manifest.hasher.save()
    else:
        from mamma_kit.core.io import sha256_file

        hashes = {str(p): sha256_file(p) for p in inputs}
    prod = producer("calibrate " + " ".join(str(t) for t in targets), hashes)
    figures = write_outputs(result, out, spec, None if no_figures else report, prod)
    if manifest is not None and out == ws.calibration:
        manifest.record(inputs, run_settings, [out], {"rms_px": result.diagnostics["rms_px"]},
                        time.perf_counter() - t0)
    if json_out:
        emit_json(summary(result, out, figures))
    else:
        d = result.diagnostics
        log.info(f"{out}: {len(result.rig)} cameras, bundle-adjusted rms {d['rms_px']:.3f} px over "
                 f"{d['events']['total']} board poses ({d['events']['shared']} shared); world from "
                 f"{d['world']['source']}")
        for c in result.rig:
            cd = result.camera_diagnostics[c.name]
            cv = cd.get("cross_validation_px", {}).get("median_px")
            log.info(f"  {c.name}: rms {cd['rms_px']:.3f} px, fx {c.K[0, 0]:.1f} px, {cd['views']} views "
                     f"({cd['shared_views']} shared)" + (f", cross-validation {cv:.2f} px" if cv is not None else ""))
        if figures:
            log.info(f"figures: {Path(figures[0]).parent}")
