"""Recipe -> a complete synthetic capture workspace with ground truth.

Writes, like a phone capture: videos/<cam>.mp4 (H.264 at each camera's VFR timestamps,
AAC/PCM audio on the camera's drifting clock, optional tmcd), board/<cam>.mp4 (the
calibration session), capture.toml; and gt/: calibration.toml, timing.toml (true clocks:
camera time -> scene time), smplx/person_<k>.npz (at the first camera's frames, in scene
time), landmarks/<cam>.npz and masks/<cam>.npz (track id = person id), recipe.toml.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mamma_kit.core import log
from mamma_kit.core.calibfile import write_calibration
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import write_json, write_toml
from mamma_kit.core.executor import run_units
from mamma_kit.core.manifest import producer
from mamma_kit.core.timingfile import write_timing
from mamma_kit.core.tracks import LandmarkTracks, MaskTracks, rle_encode
from mamma_kit.synth.recipe import Recipe, load_recipe
from mamma_kit.synth.rig import SynthCamera, build_rig, rig_of


@dataclass
class SynthResult:
    out: Path
    recipe: Recipe
    cameras: list[SynthCamera]
    paths: dict
    seconds: dict

    def summary(self) -> dict:
        return {"workspace": str(self.out), "recipe": self.recipe.name, "seed": self.recipe.seed,
                "cameras": [c.camera.name for c in self.cameras], "people": self.recipe.people_count,
                "frames": {c.camera.name: int(len(c.frame_times)) for c in self.cameras},
                "paths": self.paths, "seconds": self.seconds}


def synthesize(recipe_ref: str | Path, out: str | Path, seed: int | None = None, frames: int | None = None,
               scale: float | None = None, board: bool = True, overwrite: bool = True,
               workers: int | None = None, flash: list[float] | None = None) -> SynthResult:
    """Render a recipe into a capture workspace at ``out`` (cameras in ``workers`` processes,
    default one per CPU). ``flash``: scene times a light goes on (the recipe's [flash] table's
    other settings, else its defaults)."""
    from mamma_kit.synth.scene import build_scene

    recipe = load_recipe(recipe_ref, seed)
    if flash:
        recipe.flash = dict(recipe.flash or {}) | {"t": [float(x) for x in flash]}
    if scale is not None:
        recipe.render["scale"] = float(scale)
    if frames is not None:
        recipe.duration_s = frames / recipe.fps
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise UserError(f"{out} is not empty", "pass an empty or new folder")
    out.mkdir(parents=True, exist_ok=True)
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    cams = build_rig(recipe)
    scene = build_scene(recipe, cams)
    times["motion"] = round(time.perf_counter() - t0, 2)
    paths: dict = {"videos": {}, "board_videos": {}}

    # ---- audio for every camera (claps with sound travel, LTC) ----------------------------
    t1 = time.perf_counter()
    audio = _render_audio(recipe, cams)
    times["audio"] = round(time.perf_counter() - t1, 2)

    # ---- videos + per-frame ground truth -------------------------------------------------
    t1 = time.perf_counter()
    gt = out / "gt"
    ext = recipe.video_ext
    scene.label_contacts([sc.scene_times for sc in cams], workers)
    units = [(scene, sc, out / "videos" / f"{sc.camera.name}{ext}", audio.get(sc.camera.name), recipe, gt)
             for sc in cams]
    # one camera per process: rendering, labelling and encoding share nothing between cameras
    run_units(_render_camera, units, workers)
    for sc in cams:
        paths["videos"][sc.camera.name] = f"videos/{sc.camera.name}{ext}"
    times["render"] = round(time.perf_counter() - t1, 2)

    # ---- calibration session -------------------------------------------------------------
    if board and recipe.board is not None:
        t1 = time.perf_counter()
        paths["board_videos"] = _render_board(recipe, cams, out, scene, workers)
        times["board"] = round(time.perf_counter() - t1, 2)

    # ---- ground truth and capture.toml ---------------------------------------------------
    prod = producer(f"mamma-kit synth {recipe.path.name if recipe.path else recipe.name}")
    write_calibration(gt / "calibration.toml", rig_of(cams), diagnostics={"source": "synthetic ground truth"},
                      producer=prod)
    write_timing(gt / "timing.toml", {c.camera.name: c.clock for c in cams}, reference="scene",
                 method="gt", diagnostics={"note": "true clocks: camera time -> scene time"},
                 camera_diagnostics={c.camera.name: {"audio_start_s": c.audio_start_s} | (
                     {"exposure_s": c.exposure_s, "readout_s": c.readout_s} if recipe.flash is not None else {})
                     for c in cams},
                 producer=prod)
    scene.write_gt_bodies(gt, cams[0])
    if recipe.path is not None:
        shutil.copyfile(recipe.path, gt / "recipe.toml")
    cap = {
        "capture": {"name": recipe.name, "body_model": "open", "synthetic": True, "people": recipe.people_count},
        "cameras": {c.camera.name: {"video": paths["videos"][c.camera.name],
                                    **({"board_video": paths["board_videos"][c.camera.name]}
                                       if c.camera.name in paths["board_videos"] else {})} for c in cams},
    }
    if paths["board_videos"]:
        spec = str(recipe.board.get("spec", "charuco-a1"))
        cap["board"] = {"spec": _copy_board_spec(spec, out)}
    write_toml(out / "capture.toml", cap)
    times["total"] = round(time.perf_counter() - t0, 2)
    result = SynthResult(out, recipe, cams, paths, times)
    write_json(gt / "synth.json", result.summary())
    return result


def _render_camera(unit) -> None:
    scene, sc, vpath, audio, recipe, gt = unit
    scene.render_camera(sc, vpath, audio, recipe, gt)


def _render_audio(recipe: Recipe, cams: list[SynthCamera]) -> dict:
    """Per camera (samples_nc, start_s): claps with sound travel and reverberation, noise,
    and LTC on one channel when the recipe asks."""
    from mamma_kit.synth import audio as sa

    if not recipe.audio.get("enabled", True):  # videos without an audio stream
        return {}
    sr = int(recipe.audio["sample_rate"])
    mics = {c.camera.name: sa.Microphone(position=tuple(c.camera.center), clock=c.clock,
                                         audio_start_s=c.audio_start_s,
                                         duration_s=float(c.frame_times[-1] + 1.0 / recipe.fps - c.audio_start_s))
            for c in cams}
    claps = [sa.Clap(t_ref=c.t, position=tuple(np.asarray(c.position, float))) for c in recipe.claps]
    ltc = None
    if recipe.ltc is not None:
        ltc = sa.LtcSpec(fps=float(recipe.ltc.get("fps", 30.0)), start_tc=str(recipe.ltc.get("start", "01:00:00:00")),
                         channel=int(recipe.ltc.get("channel", 1)), drop_frame=bool(recipe.ltc.get("drop_frame", False)))
    reverb = recipe.audio.get("reverb", "weak" if float(recipe.audio.get("rt60_s", 0.0)) > 0 else "none")
    return sa.render_camera_audio(mics, claps, sample_rate=sr, snr_db=float(recipe.audio.get("snr_db", 30.0)),
                                  reverb=reverb, ltc=ltc, seed=recipe.seed + 7)


def _render_board(recipe: Recipe, cams: list[SynthCamera], out: Path, scene=None, workers: int | None = None) -> dict:
    from mamma_kit.calibration.board import load_board_spec
    from mamma_kit.synth.render import CameraRenderer

    spec = load_board_spec(str(recipe.board.get("spec", "charuco-a1")))
    backgrounds = None
    if recipe.board.get("background", "scene") == "scene" and scene is not None:
        # the board is shown where the capture happens, by cameras that do not move
        backgrounds = {c.camera.name: CameraRenderer(c.camera, scene.env).static_image() for c in cams}
    kw = dict(seed=recipe.seed + 11, duration_s=float(recipe.board.get("duration_s", 20.0)), fps=recipe.fps,
              clocks={c.camera.name: c.clock for c in cams}, closeups=bool(recipe.board.get("closeups", True)),
              n_closeups=int(recipe.board.get("n_closeups", 8)), noise_sigma=float(recipe.render.get("noise", 2.0)),
              supersample=int(recipe.board.get("supersample", 2)), progress=False,
              back=str(recipe.board.get("back", "plain")), behind=list(recipe.board.get("behind", [])),
              video_ext=recipe.video_ext, writer_options={c.camera.name: recipe.writer_options(c.camera.name)
                                                          for c in cams})
    rig = rig_of(cams)
    # one camera per process (the session's plan is the same in each: it depends on the seed and rig)
    units = [(out / "board", rig, spec, kw, c.camera.name, (backgrounds or {}).get(c.camera.name)) for c in cams]
    vids = dict(zip([c.camera.name for c in cams], run_units(_render_board_camera, units, workers)))
    return {name: str(Path(p).resolve().relative_to(out.resolve())) for name, p in vids.items()}


def _render_board_camera(unit) -> str:
    from mamma_kit.synth.board import render_board_session

    folder, rig, spec, kw, name, background = unit
    info = render_board_session(folder, rig, spec, cameras=[name], backgrounds={name: background}
                                if background is not None else None, **kw)
    return info["videos"][name]


def _copy_board_spec(spec: str, out: Path) -> str:
    """Copy the board spec into the workspace so capture.toml can point at it."""
    from mamma_kit.calibration.board import load_board_spec

    data = load_board_spec(spec).to_dict()
    dst = out / "board" / "board.toml"
    write_toml(dst, data)
    return str(dst.relative_to(out))
