"""`mamma-kit track`: person mask tracks per view -> masks/<cam>.npz (+ a picture per camera)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.app import app
from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup


@app.command("track")
def track_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace (capture.toml + videos)."),
    backend: str = typer.Option("builtin", "--backend", help="builtin (no weights), sam2 (needs --sam2-checkpoint) "
                                                              "or gt (synthetic workspaces)."),
    prompts: Optional[Path] = typer.Option(None, "--prompts", help="sam2: TOML with boxes or clicks per person "
                                                                  "(default: builtin detections)."),
    sam2_checkpoint: Optional[Path] = typer.Option(None, "--sam2-checkpoint", help="sam2: checkpoint .pt."),
    sam2_config: Optional[str] = typer.Option(None, "--sam2-config", help="sam2: model config name, e.g. "
                                                                          "configs/sam2.1/sam2.1_hiera_t.yaml."),
    chunk: int = typer.Option(64, "--chunk", min=2, help="sam2: frames per chunk (bounds memory)."),
    device: str = typer.Option("cpu", "--device", help="sam2: cpu or cuda."),
    cameras: Optional[str] = typer.Option(None, "--cameras", help="Comma-separated subset of cameras."),
    pictures: bool = typer.Option(True, "--pictures/--no-pictures", help="Write report/tracks/<cam>.png."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Per camera, a mask per person and frame with track ids that stay with the person."""
    from mamma_kit.core import log
    from mamma_kit.core.errors import UserError
    from mamma_kit.core.manifest import StageManifest, producer
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.masks.base import BACKENDS, CameraInput, get_backend

    setup(quiet, json_out)
    if backend not in BACKENDS:
        raise UserError(f"unknown --backend '{backend}'", f"use one of {', '.join(BACKENDS)}")
    if backend != "sam2" and (sam2_checkpoint or sam2_config):
        raise UserError("--sam2-checkpoint/--sam2-config need --backend sam2", "add --backend sam2")
    if prompts is not None and backend != "sam2":
        raise UserError("--prompts is for --backend sam2", "add --backend sam2 or drop --prompts")
    if prompts is not None and not prompts.is_file():
        raise UserError(f"prompts file not found: {prompts}", "check the path")
    ws = Workspace(workspace)
    cap = ws.load_capture()
    names = cap.camera_names
    if cameras:
        want = [c.strip() for c in cameras.split(",") if c.strip()]
        bad = [c for c in want if c not in names]
        if bad:
            raise UserError(f"unknown camera(s) {', '.join(bad)}", f"cameras in this workspace: {', '.join(names)}")
        names = want
    options: dict = {}
    if backend == "sam2":
        options = {"checkpoint": sam2_checkpoint, "config": sam2_config, "prompts": prompts, "chunk": chunk,
                   "device": device}
    bk = get_backend(backend, **options)
    settings = {"backend": backend, "cameras": names, "chunk": chunk if backend == "sam2" else None,
                "sam2_config": sam2_config}
    inputs = [cap.cameras[c].video for c in names]
    if backend == "gt":
        inputs += [ws.gt_dir / "masks" / f"{c}.npz" for c in names]
    for p in (prompts, sam2_checkpoint):
        if p is not None:
            inputs.append(Path(p))
    outputs = [ws.mask_file(c) for c in names]
    manifest = StageManifest(ws.cache_dir, "track", ws.root)
    state = manifest.check(inputs, settings)
    if state.fresh and not force and all(p.is_file() for p in outputs):
        log.info(f"track: up to date ({state.reason}); skipped (--force recomputes)")
        if json_out:
            emit_json({"stage": "track", "skipped": True, "reason": state.reason, "cameras": names})
        return
    t0 = time.perf_counter()
    hashes = {ws.relative(p): manifest.hasher(p) for p in inputs if Path(p).exists()}
    prod = producer(f"track --backend {backend}", hashes)
    per_cam = []
    for c in names:
        mt, summ = bk.track_camera(CameraInput(c, cap.cameras[c].video, ws.root))
        mt.producer = prod
        mt.save(ws.mask_file(c))
        if pictures:
            from mamma_kit.masks.pictures import write_track_picture

            summ["picture"] = ws.relative(write_track_picture(mt, cap.cameras[c].video,
                                                              ws.report_dir / "tracks" / f"{c}.png"))
        summ.pop("settings", None)
        per_cam.append(summ)
        log.info(f"{c}: {summ['tracks']} track(s) over {summ['frames']} frames")
    secs = time.perf_counter() - t0
    summary = {"stage": "track", "skipped": False, "backend": backend, "cameras": per_cam, "seconds": round(secs, 2)}
    manifest.record(inputs, settings, outputs, summary, secs)
    if json_out:
        emit_json(summary)
