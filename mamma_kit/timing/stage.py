"""The sync stage: capture videos -> timing.toml + timing_timeline.npz + pictures.

``sync_files`` synchronises any videos (the command line's file mode); ``run_sync`` is the
workspace stage (capture.toml's videos, calibration.toml for sound travel, a manifest in
.cache/sync.json) that `mamma-kit sync WORKSPACE` and capture-to-smplx call.
"""

from __future__ import annotations

import time
from pathlib import Path

from mamma_kit.core import log
from mamma_kit.core.manifest import FileHasher, StageManifest, producer


def _sync(videos: dict[str, Path], out_path: Path, plot_dir: Path | None, method: str | None, reference: str | None,
          settings: dict, clap_positions, mic_positions, hashes: dict, command: str, motion=None,
          flash_cache: Path | None = None) -> dict:
    from mamma_kit.core.timingfile import write_timing
    from mamma_kit.timing.plots import plot_sync
    from mamma_kit.timing.sync import sync_videos
    from mamma_kit.timing.timeline import write_timeline

    chosen = method or settings.get("method", "auto")
    res = sync_videos(videos, chosen, reference, settings, clap_positions, mic_positions, motion, flash_cache)
    write_timing(out_path, res.clocks, res.reference, res.method, diagnostics=res.diagnostics,
                 camera_diagnostics=res.camera_diagnostics, producer=producer(command, hashes))
    timeline_path = write_timeline(out_path.with_name(f"{out_path.stem}_timeline.npz"), res.clocks, res.frame_times,
                                   res.reference)
    pics = plot_sync(res, plot_dir) if plot_dir is not None else []
    summary = res.summary()
    summary.update({"timing": str(out_path), "timeline": str(timeline_path), "plots": [str(p) for p in pics]})
    for n, c in res.clocks.items():
        log.info(f"{n}: offset {c.offset * 1e3:+.4f} ms, drift {c.rate_ppm:+.2f} ppm, {c.source}, "
                 f"confidence {c.confidence:.2f}")
    return summary


def _clap_settings(settings: dict) -> tuple[dict, object]:
    cp = settings.get("clap_positions", settings.get("clap", {}).get("clap_positions"))
    settings.get("clap", {}).pop("clap_positions", None)
    settings.pop("clap_positions", None)
    return settings, cp


def _overrides(timestamps: Path | None, exposure_ms: float | None) -> dict:
    over: dict = {"timestamps": str(Path(timestamps).resolve())} if timestamps else {}
    if exposure_ms is not None:
        over["flash"] = {"exposure_s": float(exposure_ms) * 1e-3}
    return over


def sync_files(videos: dict[str, Path], out_path: Path, *, method: str | None = None, reference: str | None = None,
               preset: str | None = None, plots: bool = True, timestamps: Path | None = None,
               exposure_ms: float | None = None) -> dict:
    """Synchronise video files (no workspace): timing.toml at ``out_path``."""
    from mamma_kit.timing.sync import load_settings

    settings, cp = _clap_settings(load_settings(preset, _overrides(timestamps, exposure_ms)))
    if cp is not None:
        log.warn("clap_positions need a workspace with calibration.toml: sound travel is not corrected")
    hasher = FileHasher(None)
    plot_dir = out_path.parent / f"{out_path.stem}_plots" if plots else None
    return _sync(videos, out_path, plot_dir, method, reference, settings, None, None,
                 {n: hasher(p) for n, p in videos.items()}, "sync " + " ".join(str(p) for p in videos.values()))


def _has_motion_inputs(ws, cams: list[str]) -> bool:
    return ws.calibration.is_file() and all(ws.keypoints_file(c).is_file() for c in cams)


def _motion_inputs(ws, cams: list[str]):
    """(keypoints per camera, rig) for motion sync, or a UserError saying what to run first."""
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.errors import UserError
    from mamma_kit.core.tracks import KeypointTracks

    if not ws.calibration.is_file():
        raise UserError("motion sync needs the rig's calibration.toml", "calibrate first (or `init --calibration`)")
    missing = [c for c in cams if not ws.keypoints_file(c).is_file()]
    if missing:
        raise UserError(f"motion sync needs keypoints of the people in every view ({', '.join(missing)} have none)",
                        "run `mamma-kit track WORKSPACE` and `mamma-kit keypoints WORKSPACE` first")
    rig, _ = read_calibration(ws.calibration)
    return {c: KeypointTracks.load(ws.keypoints_file(c)) for c in cams}, rig


def run_sync(ws, *, method: str | None = None, reference: str | None = None, preset: str | None = None,
             plots: bool = True, force: bool = False, out: Path | None = None, timestamps: Path | None = None,
             exposure_ms: float | None = None) -> dict:
    """The workspace stage: every camera's clock model -> ws.timing (timing_timeline.npz beside
    it). ``out``: write another timing file instead (e.g. one method's result to compare), with
    no caching and its plots in <out stem>_plots/."""
    from mamma_kit.timing.sync import load_settings

    cap = ws.load_capture()
    videos = {n: e.video for n, e in cap.cameras.items()}
    over = dict(cap.stage_settings("sync"))
    if exposure_ms is not None:
        over["flash"] = dict(over.get("flash", {})) | {"exposure_s": float(exposure_ms) * 1e-3}
    if timestamps is not None:
        over["timestamps"] = str(Path(timestamps).resolve())
    elif over.get("timestamps"):
        over["timestamps"] = str(ws.resolve(over["timestamps"], "timestamps file"))
    settings, cp = _clap_settings(load_settings(preset, over))
    mic_positions = None
    inputs = list(videos.values()) + ([Path(settings["timestamps"])] if settings.get("timestamps") else [])
    if ws.calibration.is_file():
        # microphones at the calibrated camera centres: sound travel is corrected (with the
        # clap positions when given, else estimated with the clocks)
        from mamma_kit.core.calibfile import read_calibration

        rig, _ = read_calibration(ws.calibration)
        mic_positions = {c.name: c.center for c in rig if c.name in videos}
        if len(mic_positions) < len(videos):
            mic_positions = None
        else:
            inputs.append(ws.calibration)
    motion = None
    chosen = method or settings.get("method")
    # auto uses motion when the workspace has what it needs (track + keypoints were run)
    if chosen == "motion" or (chosen == "auto" and _has_motion_inputs(ws, list(videos))):
        motion = _motion_inputs(ws, list(videos))
        inputs += [ws.keypoints_file(c) for c in videos]
    flash_cache = ws.cache_dir / "flash"
    if cp is not None and mic_positions is None:
        log.warn("clap_positions given but no calibration.toml with every camera: sound travel is not corrected")
        cp = None
    if out is not None and Path(out).resolve() != ws.timing:
        out = Path(out)
        hasher = FileHasher(None)
        res = _sync(videos, out, out.parent / f"{out.stem}_plots" if plots else None, method, reference, settings, cp,
                    mic_positions, {ws.relative(p): hasher(p) for p in inputs}, f"sync {ws.root.name} --out {out.name}",
                    motion, flash_cache)
        return {"stage": "sync", "skipped": False, "reason": "--out", **res}
    key = {"method": method, "reference": reference, "preset": preset, "settings": settings, "clap_positions": cp,
           "plots": plots}
    manifest = StageManifest(ws.cache_dir, "sync", ws.root)
    timeline = ws.root / "timing_timeline.npz"
    state = manifest.check(inputs, key)
    if state.fresh and not force and ws.timing.is_file() and timeline.is_file():
        from mamma_kit.core.timingfile import read_timing

        log.info(f"sync: up to date ({state.reason}); skipped (--force recomputes)")
        clocks, meta = read_timing(ws.timing)
        return {"stage": "sync", "skipped": True, "reason": state.reason, "timing": str(ws.timing),
                "reference": meta.get("reference"),
                "cameras": {n: {"offset_s": c.offset, "rate_ppm": c.rate_ppm, "method": c.source,
                                "confidence": c.confidence} for n, c in clocks.items()}}
    log.info(f"sync: {state.reason}: running")
    t0 = time.perf_counter()
    hashes = {ws.relative(p): manifest.hasher(p) for p in inputs}
    out = _sync(videos, ws.timing, ws.report_dir / "sync" if plots else None, method, reference, settings, cp,
                mic_positions, hashes, f"sync {ws.root.name}", motion, flash_cache)
    secs = time.perf_counter() - t0
    manifest.record(inputs, key, [ws.timing, timeline], {"method": out.get("method")}, secs)
    return {"stage": "sync", "skipped": False, "reason": state.reason, "seconds": round(secs, 2), **out}
