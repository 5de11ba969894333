"""The calibrate stage: board videos -> calibration.toml + figures, skipped when unchanged.

``calibrate_videos`` runs on any set of board videos (the command line's file mode);
``run_calibrate`` is the workspace stage (capture.toml's board videos, a manifest in
.cache/calibrate.json) that both `mamma-kit calibrate WORKSPACE` and capture-to-smplx call.
"""

from __future__ import annotations

import time
from pathlib import Path

from mamma_kit.calibration.board import load_board_spec
from mamma_kit.calibration.solve import Settings, calibrate, summary, write_outputs
from mamma_kit.core import log
from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError
from mamma_kit.core.lens import require_solvable
from mamma_kit.core.manifest import FileHasher, StageManifest, producer


def settings_from(model: str = "radtan", detect_fps: float = 10.0, max_views: int = 40, floor: bool = True) -> Settings:
    require_solvable(model)
    return Settings(model=model, max_fps=detect_fps, max_views=max_views, floor=floor)


def _clocks(videos: dict, timing: Path | None, synced: bool) -> dict[str, ClockModel] | None:
    if timing is not None:
        from mamma_kit.core.timingfile import read_timing

        return read_timing(timing)[0]
    if synced:
        return {n: ClockModel(source="synced") for n in videos}
    return None


def _shared_clock(videos: dict[str, Path], timestamps: Path | None, timing: Path | None, synced: bool):
    """The timestamps file given, or a timestamps.csv beside the videos (unless the clocks
    are given some other way) -> SharedClock, else None."""
    from mamma_kit.calibration.clocks import find_timestamps_file, read_timestamps
    from mamma_kit.video.reader import VideoReader

    if timestamps is not None and (timing is not None or synced):
        raise UserError("--timestamps, --timing and --synced each say how the clocks relate",
                        "pass only one of them")
    if timestamps is None:
        if timing is not None or synced or len(videos) < 2:
            return None
        timestamps = find_timestamps_file(videos)
        if timestamps is None:
            return None
        log.info(f"calibrate: found {timestamps} beside the board videos")
    elif not Path(timestamps).is_file():
        raise UserError(f"timestamps file not found: {timestamps}", "check the path")
    return read_timestamps(Path(timestamps), {n: VideoReader(p).n_frames for n, p in videos.items()})


def calibrate_videos(videos: dict[str, Path], spec_src: str, out: Path, settings: Settings, *,
                     report_dir: Path | None, intrinsics: Path | None = None, timing: Path | None = None,
                     synced: bool = False, progress: bool = True, cache_dir: Path | None = None,
                     hasher: FileHasher | None = None, command: str = "calibrate",
                     timestamps: Path | None = None) -> dict:
    """Calibrate from one board video per camera; writes ``out`` (+ figures); returns the
    --json summary."""
    for n, p in videos.items():
        if not Path(p).is_file():
            raise UserError(f"board video of {n} not found: {p}", "check the path")
    spec = load_board_spec(spec_src)
    shared = _shared_clock({n: Path(p) for n, p in videos.items()}, timestamps, timing, synced)
    rig_intr = None
    if intrinsics is not None:
        from mamma_kit.calibration.formats import read_rig

        rig_intr = read_rig(intrinsics)
    result = calibrate({n: Path(p) for n, p in videos.items()}, spec, settings, intrinsics=rig_intr,
                       intrinsics_src=str(intrinsics), clocks=_clocks(videos, timing, synced), progress=progress,
                       cache_dir=cache_dir, shared_clock=shared)
    hash_of = hasher or FileHasher(None)
    inputs = [Path(p) for p in videos.values()] + [p for p in (intrinsics, timing, timestamps) if p is not None]
    prod = producer(command, {str(p): hash_of(p) for p in inputs})
    figures = write_outputs(result, out, spec, report_dir, prod)
    return summary(result, out, figures)


def run_calibrate(ws, *, board: str | None = None, settings: Settings | None = None, intrinsics: Path | None = None,
                  timing: Path | None = None, synced: bool = False, figures: bool = True, force: bool = False,
                  progress: bool = True, timestamps: Path | None = None) -> dict:
    """The workspace stage: the board videos of capture.toml -> ws.calibration."""
    cap = ws.load_capture()
    videos = {n: e.board_video for n, e in cap.cameras.items() if e.board_video is not None}
    if not videos:
        raise UserError("capture.toml names no board videos", "add board_video = \"board/NAME.mp4\" to each "
                        "[cameras.NAME], or pass the board videos themselves")
    missing = [n for n in cap.cameras if n not in videos]
    if missing:
        raise UserError(f"capture.toml has no board_video for {', '.join(missing)}",
                        "add board_video to those cameras or leave them out of capture.toml")
    spec_src = board or (str(cap.board_spec) if cap.board_spec else None)
    if spec_src is None:
        raise UserError("no board spec: capture.toml has no [board] spec", "pass --board SPEC or add "
                        "[board] spec = \"charuco.toml\" to capture.toml")
    settings = settings or Settings()
    settings.rotations = {n: e.rotation for n, e in cap.cameras.items() if e.rotation is not None}
    spec = load_board_spec(spec_src)
    inputs = [Path(p) for p in videos.values()] + ([Path(spec_src)] if Path(spec_src).is_file() else [])
    if timestamps is None and timing is None and not synced:
        from mamma_kit.calibration.clocks import find_timestamps_file

        found = find_timestamps_file({n: Path(p) for n, p in videos.items()}) if len(videos) > 1 else None
        inputs += [found] if found is not None else []
    inputs += [p for p in (intrinsics, timing, timestamps) if p is not None]
    key = {**settings.to_dict(), "spec": spec.to_dict(), "synced": synced, "figures": figures}
    manifest = StageManifest(ws.cache_dir, "calibrate", ws.root)
    state = manifest.check(inputs, key)
    if state.fresh and not force and ws.calibration.is_file():
        from mamma_kit.core.calibfile import read_calibration

        log.info(f"calibrate: up to date ({state.reason}); skipped (--force recalibrates)")
        _, diag = read_calibration(ws.calibration)
        return {"stage": "calibrate", "skipped": True, "reason": state.reason, "output": str(ws.calibration),
                "rms_px": diag["rig"].get("rms_px"),
                "cameras": {n: {"rms_px": d.get("rms_px")} for n, d in diag["cameras"].items()}}
    log.info(f"calibrate: {state.reason}: running")
    t0 = time.perf_counter()
    out = calibrate_videos(videos, spec_src, ws.calibration, settings,
                           report_dir=ws.report_dir / "calibration" if figures else None, intrinsics=intrinsics,
                           timing=timing, synced=synced, progress=progress,
                           cache_dir=ws.cache_dir / "board-detections", hasher=manifest.hasher,
                           command=f"calibrate {ws.root.name}", timestamps=timestamps)
    secs = time.perf_counter() - t0
    manifest.record(inputs, key, [ws.calibration], {"rms_px": out.get("rms_px")}, secs)
    return {"stage": "calibrate", "skipped": False, "reason": state.reason, "seconds": round(secs, 2), **out}
