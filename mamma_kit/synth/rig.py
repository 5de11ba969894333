"""Synthetic rigs: cameras from recipe specs, per-camera clocks and frame timestamps.

Scene time s is the reference clock of a synthetic capture; the action runs over
[0, duration]. Camera c starts recording ``lead_c`` seconds before s = 0 on its own clock
(t_cam = 0), so its true clock model is t_ref = (1 + rate_c) * t_cam - lead_c. It records
VFR frames (nominal 1/fps steps plus jitter) until the action has ended.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.core.camera import Camera, Rig
from mamma_kit.core.clock import ClockModel
from mamma_kit.synth.recipe import CameraSpec, Recipe, sample

TAIL_S = 0.2  # every camera keeps recording this long after the action ends


def look_at_rotation(position: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0), roll_deg: float = 0.0) -> np.ndarray:
    """World-to-camera rotation (OpenCV axes: x right, y down, z forward) for a camera at
    ``position`` looking at ``target`` with world Z up; ``roll_deg`` turns the camera about
    its optical axis (90 for a phone held in portrait)."""
    z = np.asarray(target, float) - np.asarray(position, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight up/down
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    if roll_deg:
        a = np.radians(roll_deg)
        Rz = np.array([[np.cos(a), np.sin(a), 0], [-np.sin(a), np.cos(a), 0], [0, 0, 1]])
        R = Rz @ R
    return R


def build_camera(spec: CameraSpec, rng: np.random.Generator, scale: float = 1.0) -> Camera:
    """A Camera from a spec; ``scale`` shrinks the image (and K) for fast tests."""
    w, h = spec.resolution
    roll = 0.0
    if spec.portrait:
        w, h = min(w, h), max(w, h)
        roll = 90.0
    R = look_at_rotation(spec.position, spec.look_at, roll_deg=roll)
    f = spec.focal_px
    # real lenses: principal point a little off centre, square pixels
    cx = (w - 1) / 2 + rng.uniform(-0.01, 0.01) * w
    cy = (h - 1) / 2 + rng.uniform(-0.01, 0.01) * h
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    cam = Camera(spec.name, (w, h), K, np.asarray(spec.distortion, float), "radtan", R, -R @ spec.position)
    if scale != 1.0:
        cam = cam.scaled(scale)
    return cam


@dataclass
class SynthCamera:
    camera: Camera
    clock: ClockModel  # true clock: camera time -> scene time
    frame_times: np.ndarray  # (T,) camera-clock timestamps written into the video
    audio_start_s: float  # camera time of the first audio sample
    exposure_s: float = 0.0  # each frame integrates the scene's light this long (camera clock)
    readout_s: float = 0.0  # rolling shutter: from the first row's exposure to the last's

    @property
    def scene_times(self) -> np.ndarray:
        """Scene (reference) time at which each frame was exposed."""
        return self.clock.to_ref(self.frame_times)


def build_rig(recipe: Recipe, frames: int | None = None) -> list[SynthCamera]:
    """Cameras, clocks and VFR frame timestamps for a recipe (deterministic in its seed)."""
    rng = np.random.default_rng(recipe.seed + 1)
    scale = float(recipe.render.get("scale", 1.0))
    out = []
    duration = recipe.duration_s if frames is None else frames / recipe.fps
    for i, spec in enumerate(recipe.cameras):
        clk = dict(recipe.clock) | dict(spec.clock)
        lead = abs(sample(clk.get("offset_s", 0.0), rng)) if i or clk.get("offset_first", True) else 0.0
        rate = sample(clk.get("drift_ppm", 0.0), rng) * 1e-6
        jitter = sample(clk.get("vfr_jitter_ms", 0.0), rng) * 1e-3
        audio_start = sample(clk.get("audio_start_ms", 0.0), rng) * 1e-3
        cam = build_camera(spec, rng, scale)
        clock = ClockModel(offset=-lead, rate=rate, source="gt", confidence=1.0)
        # camera-clock times covering scene time [-lead, duration + TAIL]
        t_end = clock.to_cam(duration + TAIL_S)
        n = int(np.floor(t_end * recipe.fps)) + 1
        t = np.arange(n) / recipe.fps
        if jitter > 0:  # its own stream: the rig must not depend on how many frames are rendered
            jrng = np.random.default_rng([recipe.seed + 1, i, 7])
            t = t + np.clip(jrng.normal(0, jitter, n), -0.3 / recipe.fps, 0.3 / recipe.fps)
            t[0] = 0.0
        t = np.round(t * 90000) / 90000  # what the container can hold exactly
        windows = recipe.render.get("windows_s")
        if windows:  # long takes at a fraction of the cost: only frames inside the windows are kept
            s = clock.to_ref(t)
            t = t[np.any([(s >= a) & (s < b) for a, b in windows], axis=0)]
        exposure, readout = 0.0, 0.0
        if recipe.flash is not None:  # its own stream: a flash does not change the rest of the rig
            frng = np.random.default_rng([recipe.seed + 1, i, 11])
            exposure = sample(recipe.flash.get("exposure_s", 0.5 / recipe.fps), frng)
            readout = sample(recipe.flash.get("readout_s", 0.0), frng)
        out.append(SynthCamera(cam, clock, t, audio_start, exposure, readout))
    return out


def rig_of(cams: list[SynthCamera]) -> Rig:
    return Rig([c.camera for c in cams])
