"""mamma-kit's own calibration file: calibration.toml.

::

    format = "mamma-kit-calibration"
    version = 1
    [producer]            # mamma-kit version, command, input hashes
    [diagnostics]         # rig-level summary (bundle-adjusted rms_px, ...)
    [cameras.cam0]
    size = [1920, 1080]                       # width, height (px)
    K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]
    distortion_model = "radtan"               # a model of core/lens.py's LENSES: radtan | rational |
    distortion = [k1, k2, p1, p2, k3]         #   fisheye | vicon_radial; its coefficients in the table's order
    rvec = [rx, ry, rz]                       # world -> camera rotation vector (or R = 3x3)
    t = [tx, ty, tz]                          # metres, x_cam = R x_world + t
    [cameras.cam0.diagnostics]                # per-camera rms_px, std-devs, ...
    [cameras.cam0.meta]                       # extras carried through conversions

Cameras keep their order. Reading validates every field and names the camera and field
that is wrong.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mamma_kit.core.camera import Camera, Rig, nearest_rotation, rodrigues
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_toml, write_toml

FORMAT = "mamma-kit-calibration"


def _array(value: Any, shape: tuple, cam: str, key: str, path: Path) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise UserError(f"{path.name}: camera {cam}: field '{key}' is not numeric",
                        f"write '{key}' as numbers with shape {shape}") from None
    if shape and a.size != int(np.prod(shape)):
        raise UserError(f"{path.name}: camera {cam}: field '{key}' has {a.size} numbers, expected shape {shape}",
                        "fix that field or recalibrate")
    if not np.all(np.isfinite(a)):
        raise UserError(f"{path.name}: camera {cam}: field '{key}' holds NaN or inf", "recalibrate that camera")
    return a.reshape(shape) if shape else a.reshape(-1)


def camera_from_dict(name: str, d: dict, path: Path = Path("calibration.toml")) -> Camera:
    if not isinstance(d, dict):
        raise UserError(f"{path.name}: camera {name} is not a table", "write it as [cameras.NAME]")
    for key in ("size", "K"):
        if key not in d:
            raise UserError(f"{path.name}: camera {name} is missing '{key}'", "add it or recalibrate")
    if "rvec" not in d and "R" not in d:
        raise UserError(f"{path.name}: camera {name} is missing its rotation ('rvec' or 'R')",
                        "add it or recalibrate")
    if "t" not in d:
        raise UserError(f"{path.name}: camera {name} is missing 't'", "add it or recalibrate")
    size = _array(d["size"], (2,), name, "size", path)
    K = _array(d["K"], (3, 3), name, "K", path)
    if "R" in d:
        R = _array(d["R"], (3, 3), name, "R", path)
        if abs(np.linalg.det(R) - 1) > 1e-3 or np.abs(R @ R.T - np.eye(3)).max() > 1e-3:
            raise UserError(f"{path.name}: camera {name}: 'R' is not a rotation matrix", "fix it or recalibrate")
        R = nearest_rotation(R)
    else:
        R = rodrigues(_array(d["rvec"], (3,), name, "rvec", path))
    t = _array(d["t"], (3,), name, "t", path)
    dist = _array(d.get("distortion", []), (), name, "distortion", path)
    model = str(d.get("distortion_model", "radtan"))
    return Camera(name=name, size=(int(size[0]), int(size[1])), K=K, dist=dist, model=model, R=R, t=t,
                  meta=dict(d.get("meta", {})))


def camera_to_dict(cam: Camera, diagnostics: dict | None = None) -> dict:
    d: dict[str, Any] = {
        "size": [int(cam.size[0]), int(cam.size[1])],
        "K": cam.K.tolist(),
        "distortion_model": cam.model,
        "distortion": cam.dist.tolist(),
        "rvec": cam.rvec.tolist(),
        "t": cam.t.tolist(),
    }
    if cam.meta:
        d["meta"] = cam.meta
    if diagnostics:
        d["diagnostics"] = diagnostics
    return d


def read_calibration(path: str | Path) -> tuple[Rig, dict]:
    """Read calibration.toml -> (Rig, diagnostics dict with 'rig' and per-camera entries)."""
    path = Path(path)
    data = read_toml(path, "calibration file")
    cams = data.get("cameras")
    if not isinstance(cams, dict) or not cams:
        raise UserError(f"{path.name} lists no cameras", "calibrate with `mamma-kit calibrate` or convert a file "
                        "with `mamma-kit calib convert`")
    rig = Rig([camera_from_dict(n, d, path) for n, d in cams.items()])
    diag = {"rig": data.get("diagnostics", {}), "cameras": {n: d.get("diagnostics", {}) for n, d in cams.items()},
            "producer": data.get("producer", {})}
    return rig, diag


def write_calibration(path: str | Path, rig: Rig, diagnostics: dict | None = None,
                      camera_diagnostics: dict[str, dict] | None = None, producer: dict | None = None) -> Path:
    camera_diagnostics = camera_diagnostics or {}
    data: dict[str, Any] = {"format": FORMAT, "version": 1}
    if producer:
        data["producer"] = producer
    if diagnostics:
        data["diagnostics"] = diagnostics
    data["cameras"] = {c.name: camera_to_dict(c, camera_diagnostics.get(c.name)) for c in rig}
    return write_toml(path, data)


def check_rig_covers(rig: Rig, names: list[str], path: str | Path) -> None:
    """Raise a UserError naming the cameras of a capture that the calibration lacks."""
    missing = [n for n in names if n not in rig]
    if missing:
        raise UserError(
            f"{Path(path).name} has no camera {', '.join(missing)} (it holds {', '.join(rig.names)})",
            "calibrate those cameras too, or rename the videos to match the calibration",
        )
