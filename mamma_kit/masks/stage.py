"""The track stage: capture videos -> masks/<cam>.npz (+ report/tracks/<cam>.png).

``run_track`` is what `mamma-kit track` and capture-to-smplx call. Each camera is a unit
with its own manifest (.cache/track-<cam>.json): an interrupted run keeps the cameras it
finished, and a rerun does only the rest.
"""

from __future__ import annotations

import time
from pathlib import Path

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.manifest import StageManifest, producer


def select_cameras(all_names: list[str], only: list[str] | str | None) -> list[str]:
    """``only`` (a list or comma-separated text) checked against the workspace's cameras."""
    if not only:
        return list(all_names)
    want = [c.strip() for c in only.split(",") if c.strip()] if isinstance(only, str) else list(only)
    bad = [c for c in want if c not in all_names]
    if bad:
        raise UserError(f"unknown camera(s) {', '.join(bad)}", f"cameras in this workspace: {', '.join(all_names)}")
    return want


def run_track(ws, *, backend: str = "builtin", cameras: list[str] | str | None = None, prompts: Path | None = None,
              sam2_checkpoint: Path | None = None, sam2_config: str | None = None, chunk: int = 64,
              device: str = "cpu", pictures: bool = True, force: bool = False, people: int | None = None) -> dict:
    """Person mask tracks for every camera of the workspace (see the module docstring).
    ``people``: how many people to expect (default: capture.toml's [capture] people)."""
    from mamma_kit.masks.base import BACKENDS, CameraInput, get_backend

    if backend not in BACKENDS:
        raise UserError(f"unknown --backend '{backend}'", f"use one of {', '.join(BACKENDS)}")
    if backend != "sam2" and (sam2_checkpoint or sam2_config):
        raise UserError("--sam2-checkpoint/--sam2-config need --backend sam2", "add --backend sam2")
    if prompts is not None and backend != "sam2":
        raise UserError("--prompts is for --backend sam2", "add --backend sam2 or drop --prompts")
    if prompts is not None and not Path(prompts).is_file():
        raise UserError(f"prompts file not found: {prompts}", "check the path")
    cap = ws.load_capture()
    names = select_cameras(cap.camera_names, cameras)
    people = people if people is not None else cap.people
    options: dict = {}
    if backend == "builtin" and people:
        from mamma_kit.masks.builtin import BuiltinSettings

        options = {"settings": BuiltinSettings(people=int(people))}
    if backend == "sam2":
        options = {"checkpoint": sam2_checkpoint, "config": sam2_config, "prompts": prompts, "chunk": chunk,
                   "device": device}
    bk = None  # built on first use: a fully cached run needs no backend (nor its weights)
    settings = {"backend": backend, "chunk": chunk if backend == "sam2" else None, "sam2_config": sam2_config,
                "pictures": pictures, "people": people if backend == "builtin" else None}
    t0 = time.perf_counter()
    per_cam, ran = [], []
    for c in names:
        entry = cap.cameras[c]
        inputs = [entry.video] + ([entry.board_video] if backend == "builtin" and entry.board_video else [])
        if backend == "gt":
            inputs.append(ws.gt_dir / "masks" / f"{c}.npz")
        inputs += [Path(p) for p in (prompts, sam2_checkpoint) if p is not None]
        manifest = StageManifest(ws.cache_dir, f"track-{c}", ws.root)
        out = ws.mask_file(c)
        state = manifest.check(inputs, settings)
        if state.fresh and not force and out.is_file():
            per_cam.append({"camera": c, "skipped": True, **manifest.load().get("summary", {})})
            continue
        if bk is None:
            bk = get_backend(backend, **options)
        tc = time.perf_counter()
        hashes = {ws.relative(p): manifest.hasher(p) for p in inputs if Path(p).exists()}
        mt, summ = bk.track_camera(CameraInput(c, entry.video, ws.root, board_video=entry.board_video))
        mt.producer = producer(f"track --backend {backend}", hashes)
        mt.save(out)
        outputs = [out]
        if pictures:
            from mamma_kit.masks.pictures import write_track_picture

            pic = write_track_picture(mt, entry.video, ws.report_dir / "tracks" / f"{c}.png")
            summ["picture"] = ws.relative(pic)
            outputs.append(pic)
        summ.pop("settings", None)
        manifest.record(inputs, settings, outputs, summ, time.perf_counter() - tc)
        per_cam.append({"camera": c, "skipped": False, **summ})
        ran.append(c)
        log.info(f"{c}: {summ['tracks']} track(s) over {summ['frames']} frames")
    if not ran:
        log.info("track: up to date (inputs unchanged); skipped (--force recomputes)")
    secs = time.perf_counter() - t0
    return {"stage": "track", "skipped": not ran, "reason": "inputs unchanged" if not ran else
            f"ran {', '.join(ran)}", "backend": backend, "cameras": per_cam, "seconds": round(secs, 2)}
