"""timing.toml: each camera's clock model and how it was found.

::

    format = "mamma-kit-timing"
    version = 1
    reference = "cam0"          # the camera whose clock is the reference (offset 0, rate 0)
    method = "clap"             # what the sync used overall
    [producer]
    [diagnostics]               # rig-level: loop consistency, method agreement, ...
    [cameras.cam1]
    offset_s = 0.41237          # t_ref = (1 + rate) * t_cam + offset
    rate_ppm = 12.3
    source = "clap"
    confidence = 0.97
    [cameras.cam1.diagnostics]  # per camera: residuals, peak ratios, ...
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_toml, write_toml

FORMAT = "mamma-kit-timing"


def write_timing(path: str | Path, clocks: dict[str, ClockModel], reference: str, method: str,
                 diagnostics: dict | None = None, camera_diagnostics: dict[str, dict] | None = None,
                 producer: dict | None = None) -> Path:
    camera_diagnostics = camera_diagnostics or {}
    data: dict[str, Any] = {"format": FORMAT, "version": 1, "reference": reference, "method": method}
    if producer:
        data["producer"] = producer
    if diagnostics:
        data["diagnostics"] = diagnostics
    cams = {}
    for name, clk in clocks.items():
        d = clk.to_dict()
        if camera_diagnostics.get(name):
            d["diagnostics"] = camera_diagnostics[name]
        cams[name] = d
    data["cameras"] = cams
    return write_toml(path, data)


def clocks_or_synced(path: str | Path, cameras: list[str]) -> dict[str, ClockModel]:
    """Each camera's clock from the timing file at ``path``; without one the cameras are taken as
    synchronised (identity clocks), as the match and the fit take them."""
    return read_timing(path)[0] if Path(path).is_file() else {c: ClockModel() for c in cameras}


def read_timing(path: str | Path) -> tuple[dict[str, ClockModel], dict]:
    """-> ({camera: ClockModel}, {'reference', 'method', 'diagnostics', 'cameras': per-camera diagnostics})."""
    path = Path(path)
    data = read_toml(path, "timing file")
    cams = data.get("cameras")
    if not isinstance(cams, dict) or not cams:
        raise UserError(f"{path.name} lists no cameras", "run `mamma-kit sync` first")
    clocks = {}
    for name, d in cams.items():
        if "offset_s" not in d:
            raise UserError(f"{path.name}: camera {name} is missing 'offset_s'", "run `mamma-kit sync` again")
        clocks[name] = ClockModel.from_dict(d)
    info = {"reference": data.get("reference"), "method": data.get("method"),
            "diagnostics": data.get("diagnostics", {}),
            "cameras": {n: d.get("diagnostics", {}) for n, d in cams.items()}}
    return clocks, info
