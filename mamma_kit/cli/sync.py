"""`mamma-kit sync`: every camera's clock model from claps, LTC or tmcd -> timing.toml."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from mamma_kit.cli.app import app
from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup


@app.command("sync")
def sync_cmd(
    targets: List[Path] = typer.Argument(..., help="A capture workspace folder, or two or more videos."),
    method: Optional[str] = typer.Option(None, "--method", help="auto | clap | ltc | tmcd (default: the preset's, "
                                                                  "else auto: every method the files allow)."),
    reference: Optional[str] = typer.Option(None, "--reference", help="Camera whose clock is the reference "
                                                                      "(default: the first)."),
    out: Optional[Path] = typer.Option(None, "--out", help="timing.toml to write (default: WORKSPACE/timing.toml, "
                                                           "or beside the first video)."),
    preset: Optional[str] = typer.Option(None, "--preset", help="A preset from sync/ (clap, ltc-25, ltc-30, tmcd) "
                                                                "or a TOML file."),
    plots: bool = typer.Option(True, "--plots/--no-plots", help="Write diagnostic PNGs."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Synchronise cameras: per camera offset (sub-frame), drift (ppm) and confidence.

    Clap: onsets + GCC-PHAT around each clap, all camera pairs solved jointly. LTC: timecode
    decoded on every frame. tmcd: the files' start timecode. Writes timing.toml, a per-frame
    timeline (timing_timeline.npz) and pictures (report/sync/ in a workspace).
    """
    from mamma_kit.core import log
    from mamma_kit.core.errors import UserError
    from mamma_kit.core.io import sha256_file
    from mamma_kit.core.manifest import producer
    from mamma_kit.core.timingfile import write_timing
    from mamma_kit.timing.plots import plot_sync
    from mamma_kit.timing.sync import load_settings, sync_videos
    from mamma_kit.timing.timeline import write_timeline

    setup(quiet, json_out)
    clap_positions = mic_positions = None
    if len(targets) == 1 and targets[0].is_dir():
        from mamma_kit.core.workspace import Workspace

        ws = Workspace(targets[0])
        cap = ws.load_capture()
        videos = {n: e.video for n, e in cap.cameras.items()}
        overrides = cap.stage_settings("sync")
        out_path = out or ws.timing
        plot_dir = ws.report_dir / "sync" if out is None else out_path.parent / f"{out_path.stem}_plots"
        if ws.calibration.is_file():
            from mamma_kit.core.calibfile import read_calibration

            rig, _ = read_calibration(ws.calibration)
            mic_positions = {c.name: c.center for c in rig if c.name in videos}
            if len(mic_positions) < len(videos):
                mic_positions = None
    else:
        for t in targets:
            if t.is_dir():
                raise UserError(f"{t} is a folder", "pass either one workspace folder or video files")
        videos = {}
        for t in targets:
            name = t.stem
            k = 2
            while name in videos:
                name, k = f"{t.stem}_{k}", k + 1
            videos[name] = t
        overrides = {}
        out_path = out or targets[0].parent / "timing.toml"
        plot_dir = out_path.parent / f"{out_path.stem}_plots"
    settings = load_settings(preset, overrides)
    chosen_method = method or settings.get("method", "auto")
    cp = settings.get("clap_positions", settings.get("clap", {}).get("clap_positions"))
    if cp is not None:
        clap_positions = cp
    settings.get("clap", {}).pop("clap_positions", None)
    if clap_positions is not None and mic_positions is None:
        log.warn("clap_positions given but no calibration.toml with every camera: sound travel is not corrected")
        clap_positions = None

    res = sync_videos(videos, chosen_method, reference, settings, clap_positions, mic_positions)

    inputs = {n: sha256_file(p) for n, p in videos.items()}
    prod = producer("sync " + " ".join(str(t) for t in targets), inputs)
    write_timing(out_path, res.clocks, res.reference, res.method, diagnostics=res.diagnostics,
                 camera_diagnostics=res.camera_diagnostics, producer=prod)
    timeline_path = write_timeline(out_path.parent / "timing_timeline.npz", res.clocks, res.frame_times,
                                   res.reference)
    pics = plot_sync(res, plot_dir) if plots else []
    if json_out:
        summary = res.summary()
        summary.update({"timing": str(out_path), "timeline": str(timeline_path), "plots": [str(p) for p in pics]})
        emit_json(summary)
    else:
        for n, c in res.clocks.items():
            log.info(f"{n}: offset {c.offset * 1e3:+.4f} ms, drift {c.rate_ppm:+.2f} ppm, {c.source}, "
                     f"confidence {c.confidence:.2f}")
        log.info(f"wrote {out_path}")
