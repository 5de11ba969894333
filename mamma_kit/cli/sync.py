"""`mamma-kit sync`: every camera's clock model from claps, LTC or tmcd -> timing.toml."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app


@app.command("sync", rich_help_panel="Stages")
def sync_cmd(
    targets: List[Path] = typer.Argument(..., help="A capture workspace folder, or two or more videos."),
    method: Optional[str] = typer.Option(None, "--method", help="auto | clap | ltc | tmcd | synced | timestamps | "
                                                                  "flash | motion (default: the preset's, else auto: "
                                                                  "every method the files allow, the most precise "
                                                                  "wins, the others cross-check it). synced: the "
                                                                  "cameras share one clock (genlock); timestamps: see "
                                                                  "--timestamps; flash: a light switched on or a torch "
                                                                  "flashed in view of every camera; motion: from the "
                                                                  "people's keypoints and the calibration (workspace, "
                                                                  "after track + keypoints)."),
    exposure_ms: Optional[float] = typer.Option(None, "--exposure-ms", help="Flash: the cameras' exposure time, "
                                                                            "if known (a partly lit frame is timed "
                                                                            "by it; default: estimated, else half a "
                                                                            "frame)."),
    timestamps: Optional[Path] = typer.Option(None, "--timestamps", help="CSV of every frame's time on the rig's "
                                                                         "clock (cam_id, frame_time; e.g. Caliscope's "
                                                                         "timestamps.csv); implies --method timestamps."),
    reference: Optional[str] = typer.Option(None, "--reference", help="Camera whose clock is the reference "
                                                                      "(default: the first)."),
    out: Optional[Path] = typer.Option(None, "--out", help="timing.toml to write (default: WORKSPACE/timing.toml, "
                                                           "or beside the first video)."),
    preset: Optional[str] = typer.Option(None, "--preset", help="A preset from sync/ (clap, ltc-25, ltc-30, tmcd, flash) "
                                                                "or a TOML file."),
    plots: bool = typer.Option(True, "--plots/--no-plots", help="Write diagnostic PNGs."),
    force: bool = typer.Option(False, "--force", help="Workspace: recompute even if nothing changed."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Synchronise cameras: per camera offset (sub-frame), drift (ppm) and confidence.

    Clap: onsets + GCC-PHAT around each clap, all camera pairs solved jointly. LTC: timecode
    decoded on every frame. tmcd: the files' start timecode. synced: cameras on one clock.
    timestamps: a file of every frame's time. flash: the brightness step of a light, timed
    within the frame (partly exposed frames, rolling-shutter rows). motion: the people's
    keypoints against the calibration. Writes timing.toml, a per-frame
    timeline (timing_timeline.npz) and pictures (report/sync/ in a workspace).
    """
    from mamma_kit.core.errors import UserError
    from mamma_kit.timing.stage import run_sync, sync_files

    setup(quiet, json_out)
    if timestamps is not None and method is None:
        method = "timestamps"
    if len(targets) == 1 and targets[0].is_dir():
        from mamma_kit.core.workspace import Workspace

        res = run_sync(Workspace(targets[0]), method=method, reference=reference, preset=preset, plots=plots,
                       force=force, out=out, timestamps=timestamps, exposure_ms=exposure_ms)
    else:
        videos = {}
        for t in targets:
            if t.is_dir():
                raise UserError(f"{t} is a folder", "pass either one workspace folder or video files")
            name, k = t.stem, 2
            while name in videos:
                name, k = f"{t.stem}_{k}", k + 1
            videos[name] = t
        res = sync_files(videos, out or targets[0].parent / "timing.toml", method=method, reference=reference,
                         preset=preset, plots=plots, timestamps=timestamps, exposure_ms=exposure_ms)
    if json_out:
        emit_json(res)
