"""A capture workspace: one folder that every command reads and writes (DESIGN.md s.1).

::

    <workspace>/
      capture.toml          cameras -> video files, sequence range, body model, settings
      calibration.toml      timing.toml        identities.json
      masks/<cam>.npz       landmarks/<cam>.npz  smplx/person_<k>.npz
      report/               .cache/ (stage manifests)    gt/ (synthetic only)

capture.toml::

    [capture]
    name = "my-dance"
    body_model = "open"                # or a path to SMPLX_NEUTRAL.npz
    people = 2                         # optional: how many people to expect (helps the builtin tracker)
    [board]
    spec = "charuco.toml"              # board spec used for the board videos (optional)
    [cameras.cam0]
    video = "videos/cam0.mp4"
    board_video = "board/cam0.mp4"     # optional
    rotation = "auto"                  # optional: 0, 90, 180 or 270 (clockwise) shows the videos
                                       # upright where the file's display rotation is wrong
    [sequence]                         # optional reference-time range (s)
    start_s = 0.0
    end_s = 12.0
    [settings.sync]                    # optional per-stage settings
    method = "auto"

Paths in capture.toml are resolved against the workspace and may not escape it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_toml, write_toml

STAGES = ("calibrate", "sync", "track", "keypoints", "landmarks", "match", "fill", "fit", "place", "export", "report")


ROTATIONS = (0, 90, 180, 270)


@dataclass
class CameraEntry:
    name: str
    video: Path
    board_video: Path | None = None
    rotation: int | None = None  # clockwise turn that shows the videos upright; None: the files' own


def parse_rotation(value, where: str) -> int | None:
    """A capture.toml ``rotation``: "auto" (None) or 0, 90, 180, 270 clockwise degrees."""
    if value is None or (isinstance(value, str) and value.strip().lower() == "auto"):
        return None
    try:
        deg = int(str(value).strip())
    except ValueError:
        deg = -1
    if isinstance(value, bool) or deg not in ROTATIONS:
        raise UserError(f"{where}: rotation = {value!r} is not one of auto, 0, 90, 180, 270",
                        "set rotation to the clockwise turn that shows the video upright, or \"auto\" for the "
                        "file's own display rotation")
    return deg


@dataclass
class CaptureConfig:
    name: str
    cameras: dict[str, CameraEntry]
    body_model: str = "open"
    board_spec: Path | None = None
    people: int | None = None
    start_s: float | None = None
    end_s: float | None = None
    settings: dict[str, Any] = field(default_factory=dict)
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def camera_names(self) -> list[str]:
        return list(self.cameras)

    def stage_settings(self, stage: str) -> dict[str, Any]:
        return dict(self.settings.get(stage, {}))


def _people(v) -> int | None:
    if v is None:
        return None
    # 0 is a count: a calibration-only workspace (synth recipes/board-only.toml writes it)
    if not isinstance(v, int) or isinstance(v, bool) or v < 0:
        raise UserError(f"capture.toml [capture] people = {v!r} is not a count", "write e.g. people = 2, or remove it")
    return v


def select_cameras(all_names: list[str], only: list[str] | str | None) -> list[str]:
    """``only`` (a list or comma-separated text) checked against the workspace's cameras;
    all of ``all_names`` when it is empty. UserError naming the unknown ones."""
    if not only:
        return list(all_names)
    want = [c.strip() for c in only.split(",") if c.strip()] if isinstance(only, str) else list(only)
    bad = [c for c in want if c not in all_names]
    if bad:
        raise UserError(f"unknown camera(s) {', '.join(bad)}", f"cameras in this workspace: {', '.join(all_names)}")
    return want


class Workspace:
    """Paths of a capture workspace, plus loading of its capture.toml."""

    def __init__(self, root: str | Path, must_exist: bool = True):
        self.root = Path(root).resolve()
        if must_exist and not self.root.is_dir():
            raise UserError(f"workspace not found: {root}",
                            "pass the capture folder, or create one with `mamma-kit init` or `mamma-kit synth`")

    # ---- fixed paths ----------------------------------------------------------------
    @property
    def capture_toml(self) -> Path:
        return self.root / "capture.toml"

    @property
    def calibration(self) -> Path:
        return self.root / "calibration.toml"

    @property
    def timing(self) -> Path:
        return self.root / "timing.toml"

    @property
    def masks_dir(self) -> Path:
        return self.root / "masks"

    @property
    def landmarks_dir(self) -> Path:
        return self.root / "landmarks"

    @property
    def identities(self) -> Path:
        return self.root / "identities.json"

    @property
    def smplx_dir(self) -> Path:
        return self.root / "smplx"

    @property
    def report_dir(self) -> Path:
        return self.root / "report"

    @property
    def cache_dir(self) -> Path:
        return self.root / ".cache"

    @property
    def gt_dir(self) -> Path:
        return self.root / "gt"

    def mask_file(self, cam: str) -> Path:
        return self.masks_dir / f"{cam}.npz"

    @property
    def keypoints_dir(self) -> Path:
        return self.root / "keypoints"

    def keypoints_file(self, cam: str) -> Path:
        return self.keypoints_dir / f"{cam}.npz"

    def landmarks_file(self, cam: str) -> Path:
        return self.landmarks_dir / f"{cam}.npz"

    @property
    def fill_dir(self) -> Path:
        """`mamma-kit fill`'s tracks (fill/masks, fill/keypoints, fill/landmarks: only the tracks it
        added) and fill/identities.json (the match's identities with them)."""
        return self.root / "fill"

    @property
    def place_dir(self) -> Path:
        """`mamma-kit place`'s tracks (place/masks: only the tracks it added, from the fitted bodies)
        and place/identities.json (the fit's identities with them)."""
        return self.root / "place"

    def fill_file(self, kind: str, cam: str) -> Path:
        """fill/<kind>/<cam>.npz, kind one of masks, keypoints, landmarks."""
        return self.fill_dir / kind / f"{cam}.npz"

    @property
    def export_dir(self) -> Path:
        """export/: the fit in other tools' formats (``mamma-kit export``)."""
        return self.root / "export"

    def person_file(self, k: int) -> Path:
        return self.smplx_dir / f"person_{k}.npz"

    def person_files(self) -> list[Path]:
        return sorted(self.smplx_dir.glob("person_*.npz"), key=lambda p: int(p.stem.split("_")[1]))

    @property
    def is_synthetic(self) -> bool:
        return self.gt_dir.is_dir()

    # ---- paths from config ----------------------------------------------------------
    def resolve(self, rel: str | Path, what: str = "path") -> Path:
        """Resolve a path from capture.toml against the workspace; refuse escapes."""
        p = Path(rel)
        full = (self.root / p).resolve() if not p.is_absolute() else p.resolve()
        if full != self.root and self.root not in full.parents:
            raise UserError(f"capture.toml {what} '{rel}' points outside the workspace {self.root}",
                            "move the file into the workspace (or link it) and use a relative path")
        return full

    def relative(self, path: Path) -> str:
        path = Path(path).resolve()
        try:
            return str(path.relative_to(self.root))
        except ValueError:
            return str(path)

    # ---- capture.toml ---------------------------------------------------------------
    def load_capture(self) -> CaptureConfig:
        if not self.capture_toml.is_file():
            raise UserError(f"{self.root} has no capture.toml",
                            "create one with `mamma-kit init WORKSPACE --videos ...`")
        data = read_toml(self.capture_toml, "capture.toml")
        cams = data.get("cameras")
        if not isinstance(cams, dict) or not cams:
            raise UserError("capture.toml lists no cameras", "add [cameras.NAME] tables with video = \"...\"")
        entries = {}
        for name, d in cams.items():
            if not isinstance(d, dict) or "video" not in d:
                raise UserError(f"capture.toml: camera {name} has no 'video'", "add video = \"videos/NAME.mp4\"")
            bv = d.get("board_video")
            entries[name] = CameraEntry(name, self.resolve(d["video"], f"video of {name}"),
                                        self.resolve(bv, f"board video of {name}") if bv else None,
                                        parse_rotation(d.get("rotation"), f"capture.toml [cameras.{name}]"))
        cap = data.get("capture", {})
        seq = data.get("sequence", {})
        board = data.get("board", {})
        spec = board.get("spec")
        return CaptureConfig(
            name=str(cap.get("name", self.root.name)),
            cameras=entries,
            body_model=str(cap.get("body_model", "open")),
            people=_people(cap.get("people")),
            board_spec=self.resolve(spec, "board spec") if spec else None,
            start_s=seq.get("start_s"), end_s=seq.get("end_s"),
            settings=dict(data.get("settings", {})), raw=data,
        )

    def write_capture(self, data: dict) -> Path:
        return write_toml(self.capture_toml, data)
