"""Recipes: TOML files describing a synthetic capture (rig, people, motion, audio, board).

A recipe is validated field by field; every problem is a UserError naming the field.
Ranges written as ``[lo, hi]`` are sampled per camera/person from the recipe's seed.

::

    name = "iphone-outdoor-duo"
    seed = 0
    duration_s = 4.0            # length of the capture (reference clock)
    fps = 30.0                  # nominal frame rate of every camera

    [rig]
    preset = "ring"             # ring | explicit ([[rig.cameras]])
    count = 4
    radius = 4.5                # m, ring radius
    height = 1.6                # m, camera height
    look_at = [0.0, 0.0, 1.0]
    jitter_deg = 2.0            # random aim error per camera
    resolution = [1920, 1080]
    hfov_deg = 64.0             # or focal_px
    distortion = [0.05, -0.08, 0.0, 0.0, 0.02]   # radtan k1 k2 p1 p2 k3
    portrait = [false]          # per-camera portrait (rotated 90 deg) flags, cycled

    [rig.video]                 # optional: files as phones write them (default: H.264 8-bit SDR .mp4)
    codec = "hevc"              # h264 | hevc
    bit_depth = 10              # 8 | 10 (hevc)
    transfer = "hlg"            # sdr | hlg (10-bit: BT.2020 HLG, as iPhones record by default)
    rotation = [90, 0]          # per camera, cycled: the display matrix's clockwise turn; the frames
                                # are stored turned back (a portrait camera with 90: stored landscape)
    container = "mov"           # mp4 | mov

    [rig.clock]                 # per-camera clock, values or [lo, hi] ranges
    offset_s = [0.0, 0.8]       # reference time at the camera's time zero
    drift_ppm = [-20.0, 20.0]
    vfr_jitter_ms = 0.5         # std of frame timestamp jitter
    audio_start_ms = [0.0, 25.0]

    [[rig.cameras]]             # preset = "explicit": one table per camera
    name = "cam0"
    position = [4.5, 0.0, 1.6]
    look_at = [0, 0, 1]
    resolution = [1920, 1080]
    focal_px = 1500.0
    distortion = [0, 0, 0, 0, 0]

    [people]
    count = 2
    height_m = [1.55, 1.90]     # sampled per person
    [[people.person]]           # optional per-person overrides (betas, colours)

    [motion]
    kind = "couple-dance"       # walk | turn | squat | jump | gestures | floor | couple-dance |
                                # hug | handshake | push | mixed | crowd | wander
    area_m = 3.0                # people move within this square
    leave = 1                   # wander: how many people walk out through a door once and come back

    [scene]                     # optional: a room with furniture (see synth/props.py)
    room_radius_m = 6.5         # a wall at this radius hides what is behind it (default: an
                                # outdoor backdrop 14 m away)
    doors_deg = [45.0]          # doorways in the wall (azimuths, degrees)
    chairs = 6                  # office chairs and tables, placed where nobody walks
    tables = 2

    [audio]
    enabled = true              # false: videos without an audio stream
    sample_rate = 48000
    codec = "aac"               # aac | pcm (pcm writes .mov)
    snr_db = 30.0
    reverb = "weak"             # none | weak (outdoors) | strong (a furnished room)
    claps = [{ t = 0.3, position = [0.0, 0.0, 1.5] }]
    [audio.ltc]                 # optional LTC timecode on one channel
    fps = 30.0
    start = "01:00:00:00"
    [audio.tmcd]                # optional QuickTime timecode track
    enabled = true

    [board]                     # optional calibration session
    spec = "charuco-5x7"        # calib/<spec>.toml
    duration_s = 10.0
    background = "scene"        # the board shown in the capture's own scene (the cameras stay put
                                # between board and capture), or "clutter": a random cluttered backdrop
    back = "plain"              # the board's back: plain (grey card), mirror (printed on both sides,
                                # `mamma-kit board --double-sided`) or see-through (thin paper)
    behind = ["cam3"]           # cameras that see the hand-held board only from behind

    [flash]                     # optional: a light switched on (or a torch flashed) in the scene
    t = [1.0]                   # scene time(s) the light goes on
    duration_s = 0.0            # 0: it stays on; else it goes off again after this long
    gain = 0.8                  # the light it adds to lit surfaces, as a fraction of the scene's
    exposure_s = 0.0167         # each frame integrates this long (a number, or [lo, hi] per camera)
    readout_s = 0.0             # rolling shutter: first row to last row (0: global shutter)

    [render]
    scale = 1.0                 # render at scale x resolution (tests use small scales)
    windows_s = [[0.0, 4.0], [60.0, 64.0]]   # optional: render only frames in these scene-time
                                # windows (long takes for drift benchmarks; the video's timestamps
                                # jump between windows)
    noise = 2.0                 # sensor noise std (8-bit levels)
    crf = 20
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_toml

MOTIONS = ("walk", "turn", "squat", "jump", "gestures", "floor", "couple-dance", "hug", "handshake", "push",
           "mixed", "crowd", "stand", "wander")
RECIPES_DIR = Path(__file__).resolve().parents[2] / "recipes"


@dataclass
class CameraSpec:
    name: str
    position: np.ndarray
    look_at: np.ndarray
    resolution: tuple[int, int]
    focal_px: float
    distortion: np.ndarray
    portrait: bool = False
    clock: dict[str, Any] = field(default_factory=dict)


@dataclass
class Clap:
    t: float
    position: np.ndarray


@dataclass
class Recipe:
    name: str
    seed: int
    duration_s: float
    fps: float
    cameras: list[CameraSpec]
    clock: dict[str, Any]
    people_count: int
    people: list[dict[str, Any]]
    height_range: tuple[float, float]
    motion: dict[str, Any]
    audio: dict[str, Any]
    claps: list[Clap]
    ltc: dict[str, Any] | None
    tmcd: bool
    board: dict[str, Any] | None
    render: dict[str, Any]
    path: Path | None = None
    video: dict[str, Any] = field(default_factory=dict)
    flash: dict[str, Any] | None = None
    raw: dict[str, Any] = field(default_factory=dict)
    scene: dict[str, Any] = field(default_factory=dict)

    @property
    def motion_kind(self) -> str:
        return str(self.motion.get("kind", "walk"))

    @property
    def video_ext(self) -> str:
        """.mov for [rig.video] container = "mov" or PCM audio, else .mp4."""
        return ".mov" if self.video.get("container") == "mov" or self.audio.get("codec") == "pcm" else ".mp4"

    def writer_options(self, camera: str) -> dict[str, Any]:
        """VideoWriter keywords for a camera's files ([rig.video]): codec, bits, HLG, orientation."""
        from mamma_kit.video.orientation import Orientation

        names = [c.name for c in self.cameras]
        turns = self.video.get("rotation", [0])
        cw = int(turns[names.index(camera) % len(turns)]) if camera in names else 0
        return {"codec": self.video.get("codec", "h264"), "bit_depth": int(self.video.get("bit_depth", 8)),
                "hlg": self.video.get("transfer", "sdr") == "hlg", "orientation": Orientation(cw)}


def find_recipe(name_or_path: str | Path) -> Path:
    """A recipe path, or the name of one in the repository's recipes/ folder."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    for cand in (RECIPES_DIR / f"{name_or_path}.toml", RECIPES_DIR / str(name_or_path)):
        if cand.is_file():
            return cand
    known = sorted(q.stem for q in RECIPES_DIR.glob("*.toml")) if RECIPES_DIR.is_dir() else []
    raise UserError(f"recipe not found: {name_or_path}", f"pass a .toml path or one of: {', '.join(known)}")


class _Fields:
    """Typed access to a recipe table with errors that name the field."""

    def __init__(self, data: dict, where: str):
        self.data = data if isinstance(data, dict) else {}
        self.where = where

    def err(self, key: str, msg: str) -> UserError:
        return UserError(f"recipe field {self.where}{key}: {msg}", "fix the recipe (see `mamma-kit synth --help`)")

    def num(self, key: str, default=None, lo: float | None = None, hi: float | None = None, allow_range=False):
        v = self.data.get(key, default)
        if v is None:
            if default is None:
                raise self.err(key, "is required")
            return default
        vals = v if (allow_range and isinstance(v, list)) else [v]
        if allow_range and isinstance(v, list) and len(v) != 2:
            raise self.err(key, "a range must be [lo, hi]")
        for x in vals:
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise self.err(key, f"expected a number{' or [lo, hi]' if allow_range else ''}, got {x!r}")
            if lo is not None and x < lo or hi is not None and x > hi:
                raise self.err(key, f"{x} is outside [{lo}, {hi}]")
        return [float(x) for x in v] if isinstance(v, list) else float(v)

    def vec(self, key: str, n: int, default=None) -> np.ndarray:
        v = self.data.get(key, default)
        if v is None:
            raise self.err(key, "is required")
        try:
            a = np.asarray(v, float).reshape(-1)
        except (TypeError, ValueError):
            raise self.err(key, f"expected {n} numbers") from None
        if n and a.size != n:
            raise self.err(key, f"expected {n} numbers, got {a.size}")
        return a

    def string(self, key: str, default: str | None = None, choices=None) -> str:
        v = self.data.get(key, default)
        if v is None:
            raise self.err(key, "is required")
        if not isinstance(v, str):
            raise self.err(key, f"expected a string, got {v!r}")
        if choices and v not in choices:
            raise self.err(key, f"'{v}' is not one of {', '.join(choices)}")
        return v


def sample(value, rng: np.random.Generator) -> float:
    """A number, or uniform in [lo, hi]."""
    if isinstance(value, (list, tuple)):
        return float(rng.uniform(value[0], value[1]))
    return float(value)


def _focal_from(f: _Fields, width: int) -> float:
    if "focal_px" in f.data:
        return f.num("focal_px", lo=10)
    hfov = f.num("hfov_deg", 64.0, lo=20, hi=170)
    return 0.5 * width / np.tan(np.radians(hfov) / 2)


def _cameras(rig: _Fields, rng: np.random.Generator) -> list[CameraSpec]:
    preset = rig.string("preset", "ring", ("ring", "explicit"))
    res_default = rig.vec("resolution", 2, [1920, 1080]).astype(int)
    dist_default = rig.vec("distortion", 0, [0, 0, 0, 0, 0])
    if dist_default.size not in (0, 4, 5):
        raise rig.err("distortion", "radtan takes 4 or 5 coefficients")
    portrait = rig.data.get("portrait", [False])
    portrait = portrait if isinstance(portrait, list) else [portrait]
    cams: list[CameraSpec] = []
    if preset == "ring":
        n = int(rig.num("count", 4, lo=1, hi=64))
        radius = rig.num("radius", 4.5, lo=0.5)
        height = rig.num("height", 1.6, lo=0.1)
        look = rig.vec("look_at", 3, [0, 0, 1.0])
        jitter = rig.num("jitter_deg", 0.0, lo=0, hi=20)
        start = np.radians(rig.num("start_deg", 0.0))
        for i in range(n):
            a = start + 2 * np.pi * i / n
            pos = np.array([radius * np.cos(a), radius * np.sin(a), height])
            tgt = look + rng.normal(0, np.tan(np.radians(jitter)) * radius, 3) * [1, 1, 0.5] if jitter else look
            w, h = int(res_default[0]), int(res_default[1])
            is_portrait = bool(portrait[i % len(portrait)])
            f = _focal_from(rig, max(w, h) if is_portrait else w)
            cams.append(CameraSpec(f"cam{i}", pos, np.asarray(tgt, float), (w, h), f, dist_default.copy(),
                                   is_portrait))
    else:
        tables = rig.data.get("cameras")
        if not isinstance(tables, list) or not tables:
            raise rig.err("cameras", "preset 'explicit' needs [[rig.cameras]] tables")
        for i, t in enumerate(tables):
            c = _Fields(t, f"rig.cameras[{i}].")
            res = c.vec("resolution", 2, res_default).astype(int)
            d = c.vec("distortion", 0, dist_default)
            cams.append(CameraSpec(c.string("name", f"cam{i}"), c.vec("position", 3), c.vec("look_at", 3, [0, 0, 1]),
                                   (int(res[0]), int(res[1])), _focal_from(c, int(res[0])), d,
                                   bool(t.get("portrait", False)), dict(t.get("clock", {}))))
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        raise rig.err("cameras", "camera names must be unique")
    return cams


def load_recipe(path_or_name: str | Path, seed: int | None = None) -> Recipe:
    path = find_recipe(path_or_name)
    data = read_toml(path, "recipe")
    top = _Fields(data, "")
    rseed = int(seed if seed is not None else data.get("seed", 0))
    rng = np.random.default_rng(rseed)
    rig = _Fields(data.get("rig", {}), "rig.")
    cameras = _cameras(rig, rng)
    clock = _Fields(rig.data.get("clock", {}), "rig.clock.")
    for key, lo, hi in (("offset_s", -3600, 3600), ("drift_ppm", -1000, 1000), ("vfr_jitter_ms", 0, 20),
                        ("audio_start_ms", -500, 500)):
        clock.num(key, 0.0, lo, hi, allow_range=True)
    people = _Fields(data.get("people", {}), "people.")
    n_people = int(people.num("count", 1, lo=0, hi=8))
    hr = people.num("height_m", [1.55, 1.90], lo=1.2, hi=2.2, allow_range=True)
    hr = tuple(hr) if isinstance(hr, list) else (hr, hr)
    persons = people.data.get("person", [])
    if not isinstance(persons, list):
        raise people.err("person", "use [[people.person]] tables")
    motion = _Fields(data.get("motion", {}), "motion.")
    kind = motion.string("kind", "walk", MOTIONS)
    if kind in ("couple-dance", "hug", "handshake", "push") and n_people != 2:
        raise motion.err("kind", f"'{kind}' needs people.count = 2 (got {n_people})")
    motion.num("area_m", 3.0, lo=0.5, hi=30)
    motion.num("leave", 0, lo=0, hi=8)
    scene = _scene(_Fields(data.get("scene", {}), "scene."), cameras)
    if kind == "wander" and int(motion.data.get("leave", 0)) and not scene.get("doors_deg"):
        raise motion.err("leave", "people leave through doors: set [scene] room_radius_m and doors_deg")
    audio = _Fields(data.get("audio", {}), "audio.")
    sr = int(audio.num("sample_rate", 48000, lo=8000, hi=192000))
    audio.string("codec", "aac", ("aac", "pcm"))
    audio.num("snr_db", 30.0, lo=-20, hi=120)
    audio.num("rt60_s", 0.0, lo=0, hi=3)
    audio.string("reverb", "none", ("none", "weak", "strong"))
    if not isinstance(audio.data.get("enabled", True), bool):
        raise audio.err("enabled", "expected true or false")
    claps = []
    for i, c in enumerate(audio.data.get("claps", [])):
        cf = _Fields(c, f"audio.claps[{i}].")
        claps.append(Clap(cf.num("t", lo=0), cf.vec("position", 3, [0, 0, 1.5])))
    ltc = audio.data.get("ltc")
    if ltc is not None:
        lf = _Fields(ltc, "audio.ltc.")
        lf.num("fps", 30.0, lo=23.9, hi=60.0)
        lf.string("start", "01:00:00:00")
    tmcd = bool(audio.data.get("tmcd", {}).get("enabled", False)) if isinstance(audio.data.get("tmcd"), dict) \
        else bool(audio.data.get("tmcd", False))
    board = data.get("board")
    if board is not None:
        bf = _Fields(board, "board.")
        bf.string("spec", "charuco-5x7")
        bf.num("duration_s", 10.0, lo=1, hi=600)
        bf.string("background", "scene", choices=("scene", "clutter"))
        bf.string("back", "plain", choices=("plain", "mirror", "see-through"))
        behind = board.get("behind", [])
        names = [c.name for c in cameras]
        if not isinstance(behind, list) or any(not isinstance(b, str) for b in behind):
            raise bf.err("behind", "expected a list of camera names")
        unknown = [b for b in behind if b not in names]
        if unknown:
            raise bf.err("behind", f"no camera {', '.join(unknown)} in the rig (cameras: {', '.join(names)})")
        if len(set(behind)) == len(names):
            raise bf.err("behind", "at least one camera must see the board's front")
    video = _video(_Fields(rig.data.get("video", {}), "rig.video."))
    render = _Fields(data.get("render", {}), "render.")
    render.num("scale", 1.0, lo=0.02, hi=4)
    render.num("noise", 2.0, lo=0, hi=50)
    render.num("crf", 20, lo=0, hi=51)
    windows = render.data.get("windows_s")
    if windows is not None:
        try:
            win = np.asarray(windows, float).reshape(-1, 2)
        except (TypeError, ValueError):
            raise render.err("windows_s", "expected [[start, end], ...] in seconds") from None
        if not len(win) or (win[:, 1] <= win[:, 0]).any():
            raise render.err("windows_s", "every window needs start < end")
        render.data["windows_s"] = win.tolist()
    flash = data.get("flash")
    if flash is not None:
        ff = _Fields(flash, "flash.")
        t_on = flash.get("t", 1.0)
        t_on = t_on if isinstance(t_on, list) else [t_on]
        if not t_on or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in t_on):
            raise ff.err("t", "expected a time or a list of times (s)")
        ff.num("duration_s", 0.0, lo=0)
        ff.num("gain", 0.8, lo=0, hi=20)
        ff.num("exposure_s", 0.5 / 30, lo=0, hi=1, allow_range=True)
        ff.num("readout_s", 0.0, lo=-1, hi=1, allow_range=True)
        flash = dict(flash) | {"t": [float(x) for x in t_on]}
    return Recipe(
        name=top.string("name", path.stem), seed=rseed,
        duration_s=top.num("duration_s", 4.0, lo=0.05, hi=3600), fps=top.num("fps", 30.0, lo=1, hi=240),
        cameras=cameras, clock=clock.data, people_count=n_people, people=persons, height_range=hr,
        motion=motion.data | {"kind": kind}, audio=audio.data | {"sample_rate": sr}, claps=claps,
        ltc=ltc, tmcd=tmcd, board=board, render=render.data, path=path, raw=data, flash=flash, video=video,
        scene=scene,
    )


def _scene(sf: _Fields, cameras: list[CameraSpec]) -> dict[str, Any]:
    """[scene], checked: the room's wall and doors, furniture counts."""
    out: dict[str, Any] = {"chairs": int(sf.num("chairs", 0, lo=0, hi=40)),
                           "tables": int(sf.num("tables", 0, lo=0, hi=20))}
    if "room_radius_m" in sf.data:
        r = sf.num("room_radius_m", lo=2.0, hi=50.0)
        far = max((float(np.linalg.norm(c.position[:2])) for c in cameras), default=0.0)
        if far >= r:
            raise sf.err("room_radius_m", f"{r} m puts cameras outside the room (the farthest is {far:.1f} m "
                                          "from the centre)")
        out["room_radius_m"] = r
    doors = sf.data.get("doors_deg", [])
    doors = doors if isinstance(doors, list) else [doors]
    if any(isinstance(d, bool) or not isinstance(d, (int, float)) for d in doors):
        raise sf.err("doors_deg", "expected a list of azimuths in degrees")
    if doors and "room_radius_m" not in out:
        raise sf.err("doors_deg", "doors need a wall: set room_radius_m")
    out["doors_deg"] = [float(d) for d in doors]
    return out


def _video(vf: _Fields) -> dict[str, Any]:
    """[rig.video], checked: codec, bit_depth, transfer, rotation (list), container."""
    codec = vf.string("codec", "h264", ("h264", "hevc"))
    depth = int(vf.num("bit_depth", 8, lo=8, hi=10))
    if depth not in (8, 10) or (codec == "h264" and depth != 8):
        raise vf.err("bit_depth", "8, or 10 with codec = \"hevc\"")
    transfer = vf.string("transfer", "sdr", ("sdr", "hlg"))
    if transfer == "hlg" and depth != 10:
        raise vf.err("transfer", "HLG needs bit_depth = 10")
    rot = vf.data.get("rotation", [0])
    rot = rot if isinstance(rot, list) else [rot]
    if not rot or any(isinstance(r, bool) or r not in (0, 90, 180, 270) for r in rot):
        raise vf.err("rotation", "expected 0, 90, 180 or 270 (or a list of them, cycled over the cameras)")
    return {"codec": codec, "bit_depth": depth, "transfer": transfer, "rotation": [int(r) for r in rot],
            "container": vf.string("container", "mp4", ("mp4", "mov"))}
