"""The match stage: landmarks/<cam>.npz + calibration.toml (+ timing.toml) -> identities.json.

``run_match`` is what `mamma-kit match` and capture-to-smplx call (manifest in .cache/match.json).
"""

from __future__ import annotations

import time
from pathlib import Path

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.manifest import StageManifest, producer


def run_match(ws, *, cameras: list[str] | str | None = None, calibration: Path | None = None,
              timing: Path | None = None, lam: float = 0.05, max_distance: float = 0.12, min_affinity: float = 0.25,
              people: int | None = None, window_s: float = 2.0, plots: bool = True, force: bool = False) -> dict:
    """Cross-view identities of every track (see matching.match and matching.windows). ``people``:
    how many people the capture is about (default: capture.toml's [capture] people; none: every
    person two or more cameras see)."""
    from mamma_kit.core.identities import write_identities
    from mamma_kit.core.workspace import select_cameras
    from mamma_kit.matching.match import MatchSettings, workspace_views
    from mamma_kit.matching.windows import WindowSettings, match_take

    names = ws.load_capture().camera_names if ws.capture_toml.is_file() else \
        sorted(p.stem for p in ws.landmarks_dir.glob("*.npz"))
    cams = select_cameras(names, cameras)
    if not cams:
        raise UserError(f"{ws.root} lists no cameras", "check capture.toml or run `mamma-kit landmarks` first")
    calib = Path(calibration or ws.calibration)
    if timing is not None and not Path(timing).is_file():
        raise UserError(f"timing file not found: {timing}", "run `mamma-kit sync WORKSPACE` or fix --timing")
    tpath = Path(timing) if timing is not None else (ws.timing if ws.timing.is_file() else None)
    settings = MatchSettings(lam=lam, max_distance=max_distance, min_affinity=min_affinity)
    if people is None and ws.capture_toml.is_file():
        people = ws.load_capture().people
    over_time = WindowSettings(window_s=window_s, people=people)
    inputs = [ws.landmarks_file(c) for c in cams] + [calib] + ([tpath] if tpath else []) + \
        [ws.keypoints_file(c) for c in cams if ws.keypoints_file(c).is_file()]
    manifest = StageManifest(ws.cache_dir, "match", ws.root)
    key = {"cameras": cams, "settings": settings.__dict__, "over_time": over_time.__dict__, "calibration": ws.relative(calib),
           "timing": ws.relative(tpath) if tpath else None, "plots": plots}
    state = manifest.check(inputs, key)
    if state.fresh and not force and ws.identities.is_file():
        log.info(f"match: up to date ({state.reason}); skipped (--force recomputes)")
        return {"stage": "match", "skipped": True, "reason": state.reason, **manifest.load().get("summary", {})}
    log.info(f"match: {state.reason}: running")
    t0 = time.perf_counter()
    views, kp_views, how = workspace_views(ws, cams, calib, tpath, settings)
    ident = match_take(views, kp_views, settings, over_time)
    ident.diagnostics["time_pairing"] = how
    ident.diagnostics["keypoints"] = [v.name for v in (kp_views or []) if v is not None]
    hashes = {ws.relative(p): manifest.hasher(p) for p in inputs}
    ident.producer = producer("match " + " ".join(f"{k}={v}" for k, v in settings.__dict__.items()
                                                  if k in ("lam", "max_distance", "min_affinity")), hashes)
    write_identities(ws.identities, ident)
    outputs = [ws.identities]
    picture = None
    if plots:
        from mamma_kit.matching.plots import plot_matching

        pic = plot_matching(ident, ws.report_dir / "match" / "affinities.png")
        picture = ws.relative(pic)
        outputs.append(pic)
        outputs += identity_pictures(ws, ident, cams, tpath)
    secs = time.perf_counter() - t0
    summary = {"cameras": cams, "persons": ident.persons(), "unassigned": ident.unassigned,
               "rejected": len(ident.rejected), "time_pairing": ident.diagnostics.get("time_pairing"),
               "picture": picture, "identities": ws.relative(ws.identities)}
    manifest.record(inputs, key, outputs, summary, secs)
    for p in ident.persons():
        log.info(f"person {p['id']}: {p['views']} view(s), tracks "
                 + ", ".join(f"{t['camera']}:{t['track']}" for t in p["tracks"]))
    for d in ident.diagnostics.get("set_aside", []):
        log.info(f"set aside: tracks {', '.join(d['tracks'])}: {d['reason']}")
    log.info(f"identities.json written ({len(ident.person_ids)} persons, {len(ident.rejected)} rejected "
             f"matches) in {secs:.1f} s")
    return {"stage": "match", "skipped": False, "reason": state.reason, **summary, "seconds": round(secs, 2)}


def identity_pictures(ws, ident, cams: list[str], timing: Path | None) -> list[Path]:
    """report/match/<cam>.png: who is who in one frame per camera, and what was set aside."""
    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.matching.match import camera_times
    from mamma_kit.matching.pictures import write_identity_pictures

    masks = {c: MaskTracks.load(ws.mask_file(c)) for c in cams if ws.mask_file(c).is_file()}
    if not masks:
        return []
    times, _ = camera_times(ws, list(masks), masks, timing)
    return write_identity_pictures(ws, ident, masks, times, ws.report_dir / "match")
