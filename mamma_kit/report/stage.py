"""The report as a workspace stage: ``run_report`` (what the pipeline calls) rebuilds the page
only when something it shows changed; ``report_inputs`` lists what it reads."""

from __future__ import annotations

from pathlib import Path

from mamma_kit.core import log
from mamma_kit.core.manifest import StageManifest
from mamma_kit.report.build import build_report


def report_inputs(ws) -> list[Path]:
    """Every file the report reads: the stages' outputs and pictures, and gt/ when present."""
    root = ws.root
    files = [ws.capture_toml, ws.calibration, ws.timing, ws.identities]
    for pattern in ("masks/*.npz", "fill/**/*.npz", "fill/*.json", "place/**/*.npz", "place/*.json", "landmarks/*.npz", "smplx/*.npz", "smplx/*.json", "report/calibration/*.png",
                    "report/sync/*.png", "report/tracks/*.png", "keypoints/*.npz", "report/keypoints/*.png",
                    "report/match/*.png", "report/place/*.png", "gt/**/*.npz", "gt/*.toml"):
        files += sorted(root.glob(pattern))
    return [p for p in files if p.is_file()]


def run_report(ws, *, video: bool = True, force: bool = False, progress: bool = True) -> dict:
    """The report as a pipeline stage: rebuilt only when something it shows changed
    (manifest .cache/report.json)."""
    inputs = report_inputs(ws)
    manifest = StageManifest(ws.cache_dir, "report", ws.root)
    key = {"video": video}
    index = ws.report_dir / "index.html"
    state = manifest.check(inputs, key)
    if state.fresh and not force and index.is_file():
        log.info(f"report: up to date ({state.reason}); skipped")
        return {"stage": "report", "skipped": True, "reason": state.reason, "path": str(index)}
    res = build_report(ws, video=video, progress=progress)
    manifest.record(inputs, key, [index], {"path": res["path"]}, res.get("seconds"))
    return {"stage": "report", "skipped": False, "reason": state.reason, **res}
