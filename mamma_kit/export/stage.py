"""Export as a workspace stage: ``run_export`` (what capture-to-smplx calls) writes the formats
capture.toml asks for (default: the glTF) and rewrites them only when the fit or the rig changed."""

from __future__ import annotations

from pathlib import Path

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.manifest import StageManifest
from mamma_kit.export.run import FORMATS, export_workspace

DEFAULT_FORMATS = ("gltf",)


def run_export(ws, formats=DEFAULT_FORMATS, force: bool = False) -> dict:
    """Each format into ws/export/ (manifest .cache/export.json)."""
    formats = [str(f).lower() for f in formats]
    unknown = [f for f in formats if f not in FORMATS]
    if unknown:
        raise UserError(f"capture.toml [settings.export] formats: unknown {', '.join(unknown)}",
                        f"use some of: {', '.join(FORMATS)}")
    if not ws.person_files():
        log.info("export: no fitted people (smplx/); nothing to export")
        return {"stage": "export", "skipped": True, "reason": "no fitted people"}
    inputs = [p for p in (ws.capture_toml, ws.calibration, *ws.person_files()) if p.is_file()]
    manifest = StageManifest(ws.cache_dir, "export", ws.root)
    key = {"formats": formats}
    state = manifest.check(inputs, key)
    if state.fresh and not force:
        log.info(f"export: up to date ({state.reason}); skipped")
        return {"stage": "export", "skipped": True, "reason": state.reason}
    files = []
    for fmt in formats:
        files += export_workspace(ws, fmt)["files"]
    manifest.record(inputs, key, [Path(f["path"]) for f in files], {"files": [f["path"] for f in files]})
    return {"stage": "export", "skipped": False, "reason": state.reason, "files": files}
