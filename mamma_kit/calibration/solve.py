"""`mamma-kit calibrate`: board videos -> calibrated rig with diagnostics.

Steps: detect the board in every camera's video (and, if a camera shows none, find out
which board it does show); per-camera intrinsics from selected views; still-board runs
matched across cameras (clock offsets found from the runs themselves unless a timing
model is given); a pose graph for initial extrinsics; bundle adjustment over all cameras,
still-board events and intrinsic views; the world frame from the board on the floor.
``calibrate()`` is that recipe; each step is one function below it, in the same order.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np

from mamma_kit.calibration import association as assoc
from mamma_kit.calibration.board import BoardSpec
from mamma_kit.calibration.clocks import SharedClock, shared_clock_from_videos
from mamma_kit.calibration.bundle import (BundleResult, bundle_adjust, check_connected, event_poses,
                                          init_extrinsics, pair_graph)
from mamma_kit.calibration.detect import MIN_CORNERS, Detections, detect_video, diagnose_board
from mamma_kit.calibration.intrinsics import IntrinsicResult, calibrate_camera, cross_validate
from mamma_kit.calibration.world import find_floor, up_guess, world_from_camera, world_from_floor
from mamma_kit.core import log
from mamma_kit.core.executor import default_workers, run_units
from mamma_kit.core.camera import Camera, Rig
from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError

MIN_VIEWS = 4


@dataclass
class Settings:
    model: str = "radtan"
    max_fps: float = 10.0  # detection rate (frames per second of video)
    max_views: int = 40  # views per camera for intrinsics
    still_px: float = 0.3
    sync_tol_s: float = 0.001  # with a timing model: moving frames this close in time are one pose
    offset_margin_s: float = 0.15  # still runs are shrunk by this on both ends when offsets are estimated
    max_offset_s: float | None = None  # bound on |clock offset| between cameras (None: any)
    min_shared: int = 2  # still boards a camera pair must share to count as connected
    floor: bool = True  # look for the board on the floor
    cross_validation: bool = True
    max_detect_width: int = 2000
    workers: int | None = None  # processes for detection (default: one per CPU)
    mirrored: bool = True  # also look for the board seen from behind (mirrored)
    # per camera, capture.toml's clockwise turn that shows its board video upright (in place of the
    # file's display rotation); cameras not named use their file's
    rotations: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None and v != {}}


@dataclass
class CalibrationResult:
    rig: Rig  # world frame
    diagnostics: dict
    camera_diagnostics: dict[str, dict]
    detections: dict[str, Detections]
    intrinsics: dict[str, IntrinsicResult]
    events: list
    bundle: BundleResult
    cross_validation: dict[str, dict | None]
    world_R: np.ndarray  # X_world = world_R X_rig + world_t
    world_t: np.ndarray
    warnings: list[str] = field(default_factory=list)
    pairs: dict = field(default_factory=dict)  # (camera a, camera b) -> shared still boards


def _scaled_intrinsics(cam: Camera, size: tuple[int, int], name: str, src: str) -> Camera:
    if tuple(cam.size) == tuple(size):
        return cam.copy(name=name)
    sx, sy = size[0] / cam.size[0], size[1] / cam.size[1]
    if abs(sx - sy) > 1e-3 * max(sx, sy):
        if cam.size == (size[1], size[0]):
            raise UserError(f"{src}: camera {name} was calibrated at {cam.size[0]}x{cam.size[1]} but its board video "
                            f"is {size[0]}x{size[1]} (rotated by 90 degrees)",
                            "calibrate the intrinsics from frames stored in the same orientation, or drop "
                            "--intrinsics for this camera")
        raise UserError(f"{src}: camera {name} was calibrated at {cam.size[0]}x{cam.size[1]}, its board video is "
                        f"{size[0]}x{size[1]} (another aspect ratio)", "drop --intrinsics or use a matching file")
    log.info(f"intrinsics of {name}: scaled from {cam.size[0]}x{cam.size[1]} to {size[0]}x{size[1]}")
    return cam.scaled(sx, sy).copy(name=name)


def calibrate(videos: dict[str, Path], spec: BoardSpec, settings: Settings | None = None, *,
              intrinsics: Rig | None = None, intrinsics_src: str = "--intrinsics",
              clocks: dict[str, ClockModel] | None = None, progress: bool = True,
              detections: dict[str, Detections] | None = None, cache_dir: Path | None = None,
              shared_clock: SharedClock | None = None) -> CalibrationResult:
    """Calibrate a rig from one board video per camera (see the module docstring).

    ``clocks`` (a timing model, or identical clocks for --synced) says how the videos'
    clocks relate; ``shared_clock`` (from a timestamps file) gives every video frame a time
    on one clock. With neither, the videos' own frame timestamps are checked for a shared
    absolute clock; failing that, clock offsets come from the still boards."""
    st = settings or Settings()
    names = list(videos)
    t_start = time.perf_counter()
    _check_inputs(names, intrinsics, intrinsics_src, clocks)
    # 1. detection
    dets = _detect_boards(videos, spec, st, detections, cache_dir, progress)
    t_detect = time.perf_counter() - t_start
    clocks, timing_note = _shared_clocks(names, dets, clocks, shared_clock)
    # 2. intrinsics
    intr, fixed = _intrinsics(names, dets, spec, st, intrinsics, intrinsics_src)
    cams0 = {n: intr[n].camera for n in names}
    # 3. still runs and offsets
    runs = {n: assoc.still_runs(dets[n], st.still_px) for n in names}
    for n in names:
        assoc.pose_runs(runs[n], cams0[n], spec)
    offsets = _board_offsets(names, runs, st) if clocks is None else {}
    events = _events(names, dets, runs, offsets, clocks, intr, st)
    # 4. pose graph
    events, poses = _posed_events(cams0, spec, events)
    graph = pair_graph(names, poses)
    _check_connected(names, graph, intr, dets, runs, st, clocks)
    reference, cams_init, ev_R, ev_t = _initial_extrinsics(names, graph, cams0, events, poses)
    # 5. bundle adjustment
    log.info(f"bundle adjustment: {len(names)} cameras, {len(events)} board poses "
             f"({sum(len(ev.obs) > 1 for ev in events)} seen by several cameras)")
    t_ba = time.perf_counter()
    ba = bundle_adjust(cams_init, fixed, reference, spec, events, ev_R, ev_t)
    t_ba = time.perf_counter() - t_ba
    rig_ref = Rig([ba.cameras[n] for n in names])
    # 6. world frame
    R_w, t_w, world, warnings = _world_frame(rig_ref, ba, events, spec, st, names)
    rig = rig_ref.transformed(R_w, t_w)
    # 7. diagnostics
    cv = {n: cross_validate(dets[n], spec, intr[n], st.model) if st.cross_validation and n not in fixed else None
          for n in names}
    cam_diag = {n: _camera_diagnostics(k, n, ba, events, intr[n], dets[n], videos[n], fixed, cv[n],
                                       offsets.get(n) if clocks is None else None)
                for k, n in enumerate(names)}
    seconds = {"detect": round(t_detect, 2), "bundle": round(t_ba, 2), "total": round(time.perf_counter() - t_start, 2)}
    diag = _rig_diagnostics(ba, st, spec, reference, world, events, graph,
                            timing_note or ("estimated from still boards" if len(names) > 1 else "single"), seconds)
    _warn_high_rms(diag, warnings)
    return CalibrationResult(rig, _finite(diag), _finite(cam_diag), dets, intr, events, ba, cv, R_w, t_w, warnings,
                             {k: int(e["n_agree"]) for k, e in graph.items()})


def _check_inputs(names: list[str], intrinsics: Rig | None, intrinsics_src: str,
                  clocks: dict[str, ClockModel] | None) -> None:
    """Fail before any work on inputs calibrate cannot use."""
    if len(names) < 1:
        raise UserError("no board videos given", "pass one board video per camera")
    if intrinsics is not None:
        from mamma_kit.core.camera import PIXEL_LENS_MODELS

        pix = [c.name for c in intrinsics if c.model in PIXEL_LENS_MODELS and c.name in names]
        if pix:
            raise UserError(f"{intrinsics_src}: camera {', '.join(pix)} uses the {intrinsics[pix[0]].model} lens "
                            f"model, which calibrate cannot refine or pose boards with",
                            "convert it first with `mamma-kit calib convert FILE out.json` (the closest radtan lens, "
                            "with a warning of what moves) and pass out.json")
    if clocks is not None:
        missing = [n for n in names if n not in clocks]
        if missing:
            raise UserError(f"the timing model has no clock for {', '.join(missing)}",
                            "sync these board videos first or calibrate without a timing model")


def _detect_boards(videos: dict[str, Path], spec: BoardSpec, st: Settings, detections: dict[str, Detections] | None,
                   cache_dir: Path | None, progress: bool) -> dict[str, Detections]:
    """The board in every video (``detections`` given are kept; the rest found, in parallel when
    there are workers); a camera with too few views gets the reason (most often another board)."""
    names = list(videos)
    dets: dict[str, Detections] = dict(detections or {})
    todo = [n for n in names if n not in dets]
    workers = default_workers(len(todo), st.workers)
    if workers > 1:
        # one process per camera video (decoding and ArUco search are per-frame work that
        # does not share state); the cache is read and written by the workers
        log.info(f"detecting the board in {len(todo)} videos ({workers} processes)")
        found = run_units(partial(_detect_unit, spec=spec, st=st, cache_dir=cache_dir),
                          [(n, videos[n]) for n in todo], workers)
        dets.update(zip(todo, found))
    else:
        for n in todo:
            dets[n] = _cached_detections(videos[n], spec, n, st, cache_dir, progress)
    for n in names:
        if len(dets[n].usable(spec)) < MIN_VIEWS:
            # few or no views: most often a board that differs from its spec
            err = diagnose_board(videos[n], spec, n, detections=dets[n], rotation=st.rotations.get(n))
            if err is not None:
                raise err
        n_back = int(dets[n].mirrored_f[dets[n].usable(spec)].sum())
        if n_back:
            log.info(f"{n}: {n_back} of {len(dets[n].usable(spec))} board views are seen from behind (mirrored "
                     f"back side): used as views of the same corners")
        if dets[n].rotation_deg:
            log.info(f"{n}: {Path(videos[n]).name} is shown turned {dets[n].rotation_deg} degrees clockwise; "
                     f"calibrated in that displayed frame ({dets[n].size[0]}x{dets[n].size[1]}), as every "
                     f"mamma-kit stage reads it")
    return dets


def _shared_clocks(names: list[str], dets: dict[str, Detections], clocks: dict[str, ClockModel] | None,
                   shared_clock: SharedClock | None) -> tuple[dict[str, ClockModel] | None, str | None]:
    """The clocks to match board frames with, and how they were known (None: find offsets from
    the still boards). A timestamps file, else the videos' own absolute frame timestamps, puts
    every camera on one clock: then ``dets`` get those frame times (edited in place)."""
    timing_note = None
    if clocks is not None:
        timing_note = "synced (--synced)" if all(c.source == "synced" for c in clocks.values()) else "given"
    if clocks is None and len(names) > 1:
        if shared_clock is None:
            shared_clock = shared_clock_from_videos({n: dets[n].times_f for n in names})
        if shared_clock is not None:
            for n in shared_clock.frame_times or {}:
                ft = shared_clock.frame_times[n]
                if len(dets[n].index_f) and dets[n].index_f.max() >= len(ft):
                    raise UserError(f"the timestamps hold {len(ft)} frames of camera {n} but frame "
                                    f"{int(dets[n].index_f.max())} was read from its video",
                                    "pass the timestamps written with these very videos")
                dets[n] = replace(dets[n], times_f=ft[dets[n].index_f])
            clocks = {n: ClockModel(source=shared_clock.source) for n in names}
            timing_note = shared_clock.detail
            log.info(f"calibrate: {shared_clock.detail}: moving-board frames are matched across cameras "
                     f"(no --synced needed)")
    return clocks, timing_note


def _intrinsics(names: list[str], dets: dict[str, Detections], spec: BoardSpec, st: Settings,
                intrinsics: Rig | None, intrinsics_src: str) -> tuple[dict[str, IntrinsicResult], set[str]]:
    """Per camera intrinsics from its views, or the given ones (scaled to the video) kept fixed;
    returns them and the names of the fixed cameras. All cameras must share one lens model."""
    intr: dict[str, IntrinsicResult] = {}
    fixed: set[str] = set()
    for n in names:
        fix = None
        if intrinsics is not None and n in intrinsics:
            fix = _scaled_intrinsics(intrinsics[n], dets[n].size, n, intrinsics_src)
            if fix.model != st.model:
                log.info(f"{n}: using the {fix.model} lens model of {intrinsics_src}")
            fixed.add(n)
        elif intrinsics is not None:
            log.warn(f"{intrinsics_src} has no camera {n}: calibrating its intrinsics")
        intr[n] = calibrate_camera(dets[n], spec, st.model, st.max_views, fixed=fix, min_views=MIN_VIEWS)
        log.info(f"{n}: intrinsics rms {intr[n].rms_px:.3f} px from {len(intr[n].views)} views")
    models = {intr[n].camera.model for n in names}
    if len(models) > 1:
        raise UserError(f"cameras use different lens models ({', '.join(sorted(models))})",
                        f"use --model {intr[names[0]].camera.model} or an --intrinsics file with one model")
    return intr, fixed


def _board_offsets(names: list[str], runs: dict[str, list], st: Settings) -> dict[str, float]:
    """Clock offsets (s) per camera from still-board runs the pairs share, relative to the first
    camera of the largest connected group (no timing model)."""
    if len(names) == 1:
        return {names[0]: 0.0}
    pair_off: dict[tuple[str, str], tuple[float, int]] = {}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            r = assoc.pair_offset(runs[a], runs[b], st.max_offset_s)
            if r is not None and r[1] >= st.min_shared:
                pair_off[(a, b)] = (r[0], r[1])
    comps = assoc.components(names, list(pair_off))
    main = max(comps, key=len)
    offsets, _ = assoc.solve_offsets(names, pair_off, main[0])
    return offsets


def _events(names: list[str], dets: dict[str, Detections], runs: dict[str, list], offsets: dict[str, float],
            clocks: dict[str, ClockModel] | None, intr: dict[str, IntrinsicResult], st: Settings) -> list:
    """The board poses to solve for: still holds matched across cameras, moving frames matched
    on a known clock, and each camera's intrinsic views not already inside a hold; observations
    with too few corners to pose are dropped."""
    margin = st.offset_margin_s if clocks is None else 0.0
    events = assoc.build_events(dets, runs, offsets, clocks, margin)
    if clocks is not None and st.sync_tol_s > 0:
        used = {n: set() for n in names}
        for ev in events:
            for c, fr in ev.frames.items():
                used[c] |= set(int(f) for f in fr)
        events += assoc.sync_events(dets, clocks, used, st.sync_tol_s)
    # single-camera intrinsic views not already inside a still run
    in_runs = {n: set(int(f) for r in runs[n] for f in r.frames) for n in names}
    for n in names:
        for f in intr[n].views:
            if int(f) not in in_runs[n]:
                events.append(assoc.Event("view", {n: dets[n].xy_fn2[f]}, np.nan, {n: np.array([f])}))
    # drop observations too thin to pose
    for ev in events:
        ev.obs = {c: xy for c, xy in ev.obs.items() if np.isfinite(xy[:, 0]).sum() >= MIN_CORNERS}
    return [ev for ev in events if ev.obs]


def _posed_events(cams0: dict[str, Camera], spec: BoardSpec, events: list) -> tuple[list, list[dict]]:
    """The board's pose in each camera of each event; events no camera can pose are dropped,
    and so are the observations of cameras that cannot pose theirs."""
    poses = event_poses(cams0, spec, events)
    keep = [i for i, p in enumerate(poses) if any(v is not None for v in p.values())]
    events = [events[i] for i in keep]
    poses = [poses[i] for i in keep]
    for ev, p in zip(events, poses):
        bad = [c for c, v in p.items() if v is None]
        for c in bad:
            ev.obs.pop(c)
            p.pop(c)
    return events, poses


def _check_connected(names: list[str], graph: dict, intr: dict[str, IntrinsicResult], dets: dict[str, Detections],
                     runs: dict[str, list], st: Settings, clocks: dict[str, ClockModel] | None) -> None:
    """Every camera must share enough still boards with the rest; without known clocks the
    error says what the user can do about it."""
    if len(names) <= 1:
        return
    counts = {n: len(intr[n].views) for n in names}
    try:
        check_connected(names, graph, counts, st.min_shared, near=_near_partner(names, graph, dets, runs))
    except UserError as e:
        if clocks is not None:
            raise
        holds = ", ".join(f"{n}: {len(runs[n])}" for n in names)
        raise UserError(f"{e.message}: too few still holds are shared (still holds per camera {holds}) and the "
                        f"videos' clocks are unknown (no timestamps file beside them, frame timestamps not on "
                        f"one clock)",
                        f"if the cameras were synchronised pass --synced (or --timestamps FILE); if not, sync "
                        f"the board videos and pass --timing timing.toml, or {e.hint}") from None


def _initial_extrinsics(names: list[str], graph: dict, cams0: dict[str, Camera], events: list, poses: list[dict]
                        ) -> tuple[str, dict[str, Camera], np.ndarray, np.ndarray]:
    """The reference camera (most agreeing shared views), every camera's pose from the pose
    graph, and each event's board pose in the reference frame from the camera that sees most
    of it: (reference, cameras, ev_R (E, 3, 3), ev_t (E, 3))."""
    degree = {n: sum(e["n_agree"] for (a, b), e in graph.items() if n in (a, b)) for n in names}
    reference = max(names, key=lambda n: (degree[n], -names.index(n)))
    init = init_extrinsics(names, graph, reference)
    cams_init = {n: cams0[n].copy(R=init[n][0], t=init[n][1]) for n in names}
    ev_R = np.zeros((len(events), 3, 3))
    ev_t = np.zeros((len(events), 3))
    for e, p in enumerate(poses):
        c = max(p, key=lambda k: np.isfinite(events[e].obs[k][:, 0]).sum())
        R_cb, t_cb, _ = p[c]
        Rc, tc = init[c]  # x_c = Rc x_ref + tc
        ev_R[e] = Rc.T @ R_cb
        ev_t[e] = Rc.T @ (t_cb - tc)
    return reference, cams_init, ev_R, ev_t


def _world_frame(rig_ref: Rig, ba: BundleResult, events: list, spec: BoardSpec, st: Settings, names: list[str]
                 ) -> tuple[np.ndarray, np.ndarray, dict, list[str]]:
    """X_world = R_w X_rig + t_w from the board lying still on the floor, else from the first
    camera with Z up guessed: (R_w (3, 3), t_w (3,), the world's diagnostics, warnings)."""
    still = np.array([ev.kind in ("hold",) for ev in events])
    held = np.array([ev.kind == "hold" and len(ev.obs) > 1 for ev in events])
    centres = np.einsum("eij,j->ei", ba.event_R, spec.center_b3) + ba.event_t
    up, up_src = up_guess(rig_ref, ba.event_R, held)
    floor_k, floor_all = find_floor(ba.event_R, ba.event_t, centres, still, up, rig_ref.centers()) \
        if st.floor else (None, [])
    if floor_k is not None:
        R_w, t_w, finfo = world_from_floor(ba.event_R, ba.event_t, floor_k, floor_all, spec.corners_b3)
        ev = events[floor_k]
        world = {"source": "floor", "floor_cameras": ev.cameras, "floor_time_s": ev.t_ref,
                 "floor_duration_s": ev.duration, **finfo,
                 "up_vs_guess_deg": float(np.degrees(np.arccos(np.clip(R_w[2] @ up, -1, 1))))}
        return R_w, t_w, world, []
    R_w, t_w = world_from_camera(rig_ref, up, names[0])
    msg = (f"no board lying on the floor was found: the world frame is camera {names[0]}'s position with Z up "
           f"guessed from {up_src}; lay the board flat on the floor, still, for 2 seconds where most cameras see "
           f"it, to pin the floor at z = 0")
    log.warn(msg)
    return R_w, t_w, {"source": "first-camera", "camera": names[0], "up_from": up_src}, [msg]


def _camera_diagnostics(k: int, n: str, ba: BundleResult, events: list, intr: IntrinsicResult, det: Detections,
                        video: Path, fixed: set[str], cv: dict | None, board_offset: float | None) -> dict:
    """Camera ``n`` (index ``k`` in the bundle): residuals after the bundle, views, intrinsics,
    uncertainties, what was read from its video, its board clock offset and cross-validation."""
    m = (ba.obs_cam == k)
    mi = m & ba.inlier
    res = ba.residual[mi]
    ev_ids = np.unique(ba.obs_evt[mi])
    per_view = [float(np.sqrt(np.mean(np.sum(ba.residual[mi & (ba.obs_evt == e)] ** 2, 1)))) for e in ev_ids]
    shared = int(sum(1 for e in ev_ids if len(events[e].obs) > 1))
    d = {
        "rms_px": float(np.sqrt(np.mean(np.sum(res ** 2, 1)))) if len(res) else float("nan"),
        "intrinsics_rms_px": intr.rms_px,
        "views": int(len(ev_ids)), "shared_views": shared, "intrinsic_views": int(len(intr.views)),
        "corners": int(mi.sum()), "outlier_corners": int((m & ~ba.inlier).sum()),
        "per_view_rms_px": per_view,
        "per_view_max_px": float(max(per_view)) if per_view else float("nan"),
        "coverage": float(intr.coverage), "max_tilt_deg": float(intr.max_tilt_deg),
        "intrinsics_fixed": n in fixed,
        "intrinsics_std": intr.std,
        "bundle_std": ba.std.get(n, {}),
        "video": str(video), "size": list(det.size), "rotation_deg": det.rotation_deg,
        "frames_detected": int((det.n_corners_f >= MIN_CORNERS).sum()),
        "frames_seen_from_behind": int((det.mirrored_f & (det.n_corners_f >= MIN_CORNERS)).sum()),
        "frames_sampled": int(len(det.times_f)), "frame_step": int(det.frame_step),
    }
    if board_offset is not None:
        d["board_clock_offset_s"] = board_offset
    if cv is not None:
        d["cross_validation_px"] = {k2: cv[k2] for k2 in ("median_px", "p95_px", "max_px")}
    return d


def _rig_diagnostics(ba: BundleResult, st: Settings, spec: BoardSpec, reference: str, world: dict, events: list,
                     graph: dict, timing: str, seconds: dict[str, float]) -> dict:
    """The rig's diagnostics: the bundle's error and observations, the events by kind, the views
    each camera pair shares, how the clocks were known, the world frame, times and settings."""
    return {
        "rms_px": float(ba.rms_px),
        "model": st.model,
        "board": spec.to_dict(),
        "reference_camera": reference,
        "world": world,
        "events": {"total": len(events), "shared": int(sum(len(ev.obs) > 1 for ev in events)),
                   "holds": int(sum(ev.kind == "hold" for ev in events)),
                   "sync": int(sum(ev.kind == "sync" for ev in events)),
                   "views": int(sum(ev.kind == "view" for ev in events))},
        "shared_views": {f"{a}-{b}": int(e["n_agree"]) for (a, b), e in graph.items()},
        "timing": timing,
        "observations": int(ba.inlier.sum()), "outliers": int((~ba.inlier).sum()),
        "bundle_rounds": ba.cost_history,
        "seconds": seconds,
        "settings": st.to_dict(),
    }


def _warn_high_rms(diag: dict, warnings: list[str]) -> None:
    """Put the warnings in the diagnostics, with one more when the bundle's error is high (most
    often a board spec whose sizes are not the print's)."""
    if warnings:
        diag["warnings"] = warnings
    overall = diag["rms_px"]
    if overall > 1.0:
        msg = f"the bundle-adjusted reprojection error is high ({overall:.2f} px): check the board spec's sizes " \
              f"(measure the print) and that the board is flat"
        log.warn(msg)
        warnings.append(msg)
        diag["warnings"] = warnings


def _finite(obj):
    """Diagnostics without NaN/inf (they become absent): TOML/JSON-safe."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items() if not (isinstance(v, float) and not np.isfinite(v))}
    if isinstance(obj, (list, tuple)):
        return [None if isinstance(v, float) and not np.isfinite(v) else _finite(v) for v in obj]
    if isinstance(obj, np.generic):
        return _finite(obj.item())
    return obj


def write_outputs(result: CalibrationResult, out: Path, spec: BoardSpec, report_dir: Path | None,
                  producer: dict | None = None) -> list[str]:
    """calibration.toml (with diagnostics) and, unless report_dir is None, the figures."""
    from mamma_kit.core.calibfile import write_calibration

    figures: list[str] = []
    if report_dir is not None:
        from mamma_kit.calibration.plots import write_figures

        figures = write_figures(result, spec, report_dir)
        result.diagnostics["figures"] = figures
    write_calibration(out, result.rig, result.diagnostics, result.camera_diagnostics, producer)
    return figures


def _detect_unit(unit: tuple[str, Path], spec: BoardSpec, st: Settings, cache_dir: Path | None) -> Detections:
    name, video = unit
    return _cached_detections(video, spec, name, st, cache_dir, False)


def _cached_detections(video: Path, spec: BoardSpec, name: str, st: Settings, cache_dir: Path | None,
                       progress: bool) -> Detections:
    """Detections of one video, reused from ``cache_dir`` when the video (size, mtime), the
    board spec and the detection settings are unchanged."""
    from mamma_kit.core.io import read_npz, sha256_json, write_npz

    key = None
    if cache_dir is not None:
        stt = Path(video).stat()
        key = sha256_json({"video": str(Path(video).resolve()), "size": stt.st_size, "mtime": stt.st_mtime_ns,
                           "spec": spec.to_dict(), "fps": st.max_fps, "width": st.max_detect_width,
                           "mirrored": st.mirrored, "rotation": st.rotations.get(name), "v": 3})
        f = Path(cache_dir) / f"{name}.npz"
        if f.is_file():
            try:
                z = read_npz(f, "detection cache")
                if str(z["key"]) == key:
                    log.info(f"{name}: board detections reused from {f}")
                    return Detections.from_npz_dict(name, str(video), z)
            except Exception:
                pass
    log.info(f"detecting the board in {video}")
    d = detect_video(video, spec, name, max_fps=st.max_fps, max_detect_width=st.max_detect_width, progress=progress,
                     mirrored=st.mirrored, rotation=st.rotations.get(name))
    if key is not None:
        write_npz(Path(cache_dir) / f"{name}.npz", key=np.array(key), **d.to_npz_dict())
    return d


def _near_partner(names, graph, dets, runs) -> dict[str, str]:
    """For each camera, the other camera it comes closest to sharing a still board with:
    the most (non-agreeing) pairs of still runs, else the most detections."""
    out = {}
    for n in names:
        best, score = None, -1
        for m in names:
            if m == n:
                continue
            e = graph.get((n, m)) or graph.get((m, n))
            s = (e["n"] if e else 0) * 1000 + len(runs[m])
            if s > score:
                best, score = m, s
        if best:
            out[n] = best
    return out


def summary(result: CalibrationResult, output: Path | None = None, figures: list[str] | None = None) -> dict:
    """The --json summary: per-camera rms_px and the bundle-adjusted overall rms_px."""
    cams = {}
    for c in result.rig:
        d = result.camera_diagnostics[c.name]
        cams[c.name] = {
            "rms_px": d["rms_px"], "intrinsics_rms_px": d["intrinsics_rms_px"], "views": d["views"],
            "shared_views": d["shared_views"], "fx": float(c.K[0, 0]), "fy": float(c.K[1, 1]),
            "cx": float(c.K[0, 2]), "cy": float(c.K[1, 2]), "distortion": c.dist.tolist(),
            "center_m": c.center.tolist(), "size": list(c.size),
            "focal_std_px": d["intrinsics_std"].get("fx"),
            "cross_validation_px": d.get("cross_validation_px"),
            "frames_detected": d["frames_detected"], "frames_seen_from_behind": d["frames_seen_from_behind"],
        }
    out = {"rms_px": result.diagnostics["rms_px"], "cameras": cams, "world": result.diagnostics["world"],
           "events": result.diagnostics["events"], "warnings": result.warnings,
           "timing": result.diagnostics.get("timing")}
    if output is not None:
        out["output"] = str(output)
    if figures is not None:
        out["figures"] = figures
    return out
