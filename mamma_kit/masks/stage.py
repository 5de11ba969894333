"""The track stage: capture videos -> masks/<cam>.npz (+ report/tracks/<cam>.png).

``run_track`` is what `mamma-kit track` and capture-to-smplx call. Each camera is a unit
with its own manifest (.cache/track-<cam>.json): an interrupted run keeps the cameras it
finished, and a rerun does only the rest.
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.executor import run_units
from mamma_kit.core.manifest import StageManifest, producer
from mamma_kit.core.workspace import select_cameras


def run_track(ws, *, backend: str = "builtin", cameras: list[str] | str | None = None, prompts: Path | None = None,
              sam2_checkpoint: Path | None = None, sam2_config: str | None = None, chunk: int = 64,
              device: str = "cpu", pictures: bool = True, force: bool = False, people: int | None = None,
              plate: bool = True) -> dict:
    """Person mask tracks for every camera of the workspace (see the module docstring).
    ``people``: how many people to expect, for the builtin tracker's blob splitting (default:
    capture.toml's [capture] people)."""
    from mamma_kit.masks.backends import BACKENDS

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
    if backend == "builtin" and (people or not plate):
        from mamma_kit.masks.builtin import BuiltinSettings

        options = {"settings": BuiltinSettings(people=int(people) if people else None, use_board_plate=plate)}
    if backend == "sam2":
        options = {"checkpoint": sam2_checkpoint, "config": sam2_config, "prompts": prompts, "chunk": chunk,
                   "device": device}
    settings = {"backend": backend, "chunk": chunk if backend == "sam2" else None, "sam2_config": sam2_config,
                "pictures": pictures, "people": people if backend == "builtin" else None,
                "plate": plate if backend == "builtin" else None}
    t0 = time.perf_counter()
    per_cam, todo = {}, []
    for c in names:
        manifest = StageManifest(ws.cache_dir, f"track-{c}", ws.root)
        state = manifest.check(_inputs(ws, cap.cameras[c], backend, prompts, sam2_checkpoint),
                               {**settings, "rotation": cap.cameras[c].rotation})
        if state.fresh and not force and ws.mask_file(c).is_file():
            per_cam[c] = {"camera": c, "skipped": True, **manifest.load().get("summary", {})}
        else:
            todo.append(c)
    if todo:
        unit = partial(_track_one, root=ws.root, backend=backend, options=options, settings=settings,
                       pictures=pictures, prompts=prompts, sam2_checkpoint=sam2_checkpoint)
        # cameras are independent: one process each (sam2 holds one model: in this process)
        for c, summ in zip(todo, run_units(unit, todo, 1 if backend == "sam2" else None)):
            per_cam[c] = {"camera": c, "skipped": False, **summ}
            log.info(f"{c}: {summ['tracks']} track(s) over {summ['frames']} frames")
    ran = todo
    if not ran:
        log.info("track: up to date (inputs unchanged); skipped (--force recomputes)")
    secs = time.perf_counter() - t0
    return {"stage": "track", "skipped": not ran, "reason": "inputs unchanged" if not ran else
            f"ran {', '.join(ran)}", "backend": backend, "cameras": [per_cam[c] for c in names],
            "seconds": round(secs, 2)}


def _inputs(ws, entry, backend: str, prompts, sam2_checkpoint) -> list[Path]:
    inputs = [entry.video] + ([entry.board_video] if backend == "builtin" and entry.board_video else [])
    if backend == "pose":
        from mamma_kit.keypoints.runtime import DETECTOR, LANDMARKER, model_path

        inputs += [model_path(DETECTOR), model_path(LANDMARKER)]
    if backend == "gt":
        inputs.append(ws.gt_dir / "masks" / f"{entry.name}.npz")
    return inputs + [Path(p) for p in (prompts, sam2_checkpoint) if p is not None]


_BACKENDS: dict = {}


def _track_one(c: str, root: Path, backend: str, options: dict, settings: dict, pictures: bool, prompts,
               sam2_checkpoint) -> dict:
    """One camera: masks/<c>.npz, its picture and its manifest (runs in a worker process)."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.masks.backends import get_backend
    from mamma_kit.masks.base import CameraInput

    ws = Workspace(root)
    entry = ws.load_capture().cameras[c]
    inputs = _inputs(ws, entry, backend, prompts, sam2_checkpoint)
    manifest = StageManifest(ws.cache_dir, f"track-{c}", ws.root)
    tc = time.perf_counter()
    hashes = {ws.relative(p): manifest.hasher(p) for p in inputs if Path(p).exists()}
    key = (backend, repr(sorted(options.items())))
    if key not in _BACKENDS:  # built once per process (sam2 loads a model)
        _BACKENDS[key] = get_backend(backend, **options)
    mt, summ = _BACKENDS[key].track_camera(
        CameraInput(c, entry.video, ws.root, board_video=entry.board_video, rotation=entry.rotation))
    mt.producer = producer(f"track --backend {backend}", hashes)
    out = ws.mask_file(c)
    mt.save(out)
    outputs = [out]
    if pictures:
        from mamma_kit.masks.pictures import write_track_picture

        pic = write_track_picture(mt, entry.video, ws.report_dir / "tracks" / f"{c}.png", entry.rotation)
        summ["picture"] = ws.relative(pic)
        outputs.append(pic)
    summ.pop("settings", None)
    manifest.record(inputs, {**settings, "rotation": entry.rotation}, outputs, summ, time.perf_counter() - tc)
    return summ
