"""The fit stage: calibration.toml, timing.toml, landmarks/, keypoints/ (when there) and
identities.json -> smplx/person_<k>.npz and smplx/fit_report.json.

``fit_workspace`` is what `mamma-kit fit WORKSPACE` and capture-to-smplx call; the report says
per stage what each energy contributes and the landmark and keypoint reprojection per camera.
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from mamma_kit.fitting.checks import check_fit, rest_heights, summary_lines
from mamma_kit.fitting.stages import FitConfig, Fitter, FitResult
from mamma_kit.fitting.viewcheck import camera_findings, gather

REPORT_NAME = "fit_report.json"


REPORT_BLOCK = 256  # output frames whose reprojection is measured at once


def _summary(e_parts: list[np.ndarray], rel_parts: list[np.ndarray] | None, count_key: str) -> dict:
    """mean / median / 90th percentile of one camera's errors (parts in person-major order)."""
    e = np.concatenate(e_parts) if e_parts else np.zeros(0, np.float32)
    if not len(e):
        return {count_key: 0}
    out = {"mean": float(e.mean()), "median": float(np.median(e)), "p90": float(np.percentile(e, 90))}
    if rel_parts is not None:
        out["median_pct_size"] = float(np.median(np.concatenate(rel_parts)))
    return {**out, count_key: int(len(e))}


def _blocks(fitter, result: FitResult, raw: bool = False):
    """(output frame slice, that block's data as fitted) over the take, REPORT_BLOCK frames at a time;
    ``raw``: as read, with the views the fit set aside."""
    T = len(result.frame_times)
    for a in range(0, T, REPORT_BLOCK):
        s = slice(a, min(a + REPORT_BLOCK, T))
        yield s, fitter.data.slice_frames(s) if raw else fitter.frames(s)


def reprojection_report(model, fitter, result: FitResult, min_vis: float = 0.5) -> dict:
    """Per camera: mean / median / 90th percentile px between the observed landmarks
    (visibility > min_vis) and the fitted bodies' projected landmarks (the take read a block of
    frames at a time through ``fitter.frames``: the data as fitted)."""
    import torch

    from mamma_kit.body.lbs import pose_restricted
    from mamma_kit.fitting.energies import pose_dict
    from mamma_kit.fitting.projection import RigTensors

    cams = RigTensors.from_rig(fitter.data.rig).to(torch.float32)
    C, P = len(fitter.data.cameras), len(result.person_ids)
    parts = [[[] for _ in range(P)] for _ in range(C)]
    for s, data in _blocks(fitter, result):
        with torch.no_grad():
            v, _ = pose_restricted(model, pose_dict(torch.as_tensor(result.pose[:, s], dtype=torch.float32),
                                                    torch.as_tensor(result.transl[:, s], dtype=torch.float32),
                                                    torch.as_tensor(result.betas, dtype=torch.float32)))
            uv, valid = cams.project(v[None])
        err = np.linalg.norm(uv.numpy() - data.xy, axis=-1)  # (C, P, T, L)
        use = (data.vis > min_vis) & valid.numpy()
        for i in range(C):
            for p in range(P):
                parts[i][p].append(err[i, p][use[i, p]])
    return {n: _summary([e for pp in parts[i] for e in pp], None, "landmarks") for i, n in enumerate(fitter.data.cameras)}


def keypoint_report(model, fitter, result: FitResult, regressor, min_vis: float = 0.5, hands: bool = False) -> dict:
    """Per camera: median / mean / 90th percentile px between BlazePose's points (visibility x
    presence > min_vis) and the fitted bodies' regressed points, and the median in % of the person's
    size in the view; ``hands``: the same for the hand points (data.hand_xy, where the hand model was
    sure) with a hand regressor."""
    import torch

    from mamma_kit.fitting.kinematics import BodyKinematics, so3_exp
    from mamma_kit.fitting.projection import RigTensors

    kin = BodyKinematics(model, regressor=regressor)
    cams = RigTensors.from_rig(fitter.data.rig)
    C, P = len(fitter.data.cameras), len(result.person_ids)
    parts = [[[] for _ in range(P)] for _ in range(C)]
    rels = [[[] for _ in range(P)] for _ in range(C)]
    for s, data in _blocks(fitter, result):
        with torch.no_grad():
            f = kin.forward(torch.as_tensor(result.betas), so3_exp(torch.as_tensor(result.pose[:, s])),
                            torch.as_tensor(result.transl[:, s]), dtype=torch.float64)
            uv, valid = cams.project(f.v[None])
        xy, vis = (data.hand_xy, data.hand_vis) if hands else (data.kp_xy, data.kp_vis)
        err = np.linalg.norm(uv.numpy() - xy, axis=-1)  # (C, P, T, K)
        use = (vis > min_vis) & valid.numpy() & (data.kp_size[..., None] > 0)
        rel = err / np.maximum(data.kp_size[..., None], 1e-6) * 100
        for i in range(C):
            for p in range(P):
                parts[i][p].append(err[i, p][use[i, p]])
                rels[i][p].append(rel[i, p][use[i, p]])
    return {n: _summary([e for pp in parts[i] for e in pp], [r for pp in rels[i] for r in pp], "points")
            for i, n in enumerate(fitter.data.cameras)}


def fit_workspace(ws, cameras: int | None = None, camera_list: list[str] | None = None, stages: int = 4,
                  body_model: str | None = None, config: FitConfig | None = None, command: str = "mamma-kit fit",
                  force: bool = False, threads: int | None = None) -> dict:
    """Fit every matched person of a workspace and write the results (see module doc)."""
    import torch

    from mamma_kit.body.model import load_body_model, resolve_body_model_path
    from mamma_kit.core import log
    from mamma_kit.core.io import write_json
    from mamma_kit.core.manifest import StageManifest, producer
    from mamma_kit.core.smplxfile import SmplxResult, write_smplx_result
    from mamma_kit.fitting.data import open_fit_data

    if threads:
        torch.set_num_threads(int(threads))
    if body_model is None:
        body_model = ws.load_capture().body_model if ws.capture_toml.is_file() else "open"
    cfg = dataclasses.replace(config or FitConfig(), stages=stages)  # the caller's config stays as it was
    model = load_body_model(body_model)
    t0 = time.perf_counter()
    data = open_fit_data(ws, cameras, camera_list, n_landmarks=len(model.landmark_ids))
    if data.landmark_set and not data.landmark_set.startswith(model.name):
        log.warn(f"landmarks were made for '{data.landmark_set}', fitting body model '{model.name}'")
    model_path = resolve_body_model_path(body_model)
    inputs = list(data.inputs) + [model_path]
    settings = {"cameras": data.cameras, "stages": stages, "body_model": model.sha256,
                "config": {k: (v.__dict__ if hasattr(v, "__dict__") else v) for k, v in cfg.__dict__.items()}}
    manifest = StageManifest(ws.cache_dir, "fit", ws.root)
    report_path = ws.smplx_dir / REPORT_NAME
    state = manifest.check(inputs, settings)
    if state.fresh and not force and report_path.is_file():
        log.info(f"fit: up to date ({state.reason}); skipped (--force recomputes)")
        from mamma_kit.core.io import read_json

        rep = read_json(report_path)
        rep["skipped"] = True
        return rep
    log.info(f"fit: {len(data.person_ids)} person(s), {len(data.frame_times)} frames, cameras "
             f"{', '.join(data.cameras)}, stages 1-{stages}")
    fitter = Fitter(model, data, cfg)
    from mamma_kit.fitting.units import fit_in_units

    result = fit_in_units(fitter)  # Fitter.fit with its chunks as units of the executor
    set_aside = fitter.set_aside  # views whose keypoints missed the others' consensus: they weighed 0 there
    if set_aside:
        views = "; ".join(f"{c} " + ", ".join(f"person {p} {n['keypoints']} / {n['landmarks']}" for p, n in ps.items())
                          for c, ps in set_aside.items())
        log.info(f"fit: views set aside where their keypoints miss the other views (frames of keypoints / "
                 f"landmarks): {views}")
    secs = time.perf_counter() - t0
    hashes = {ws.relative(p): manifest.hasher(p) for p in inputs}
    written = []
    for i, pid in enumerate(result.person_ids):
        prod = producer(command, hashes) | {"reference": data.reference, "frame_camera": data.frame_camera,
                                            "person": int(pid), "cameras": data.cameras, "stages": stages}
        r = SmplxResult.from_params(result.params(i), result.joints[i], result.frame_times, result.fps,
                                    model.name, model.sha256, model.gender, prod)
        written.append(write_smplx_result(ws.person_file(pid), r))
    for old in ws.person_files():  # a person from an earlier run that this run did not fit
        if old not in written:
            old.unlink()
    world, obs = gather(model, _blocks(fitter, result, raw=True), result.pose, result.transl, result.betas)
    views = camera_findings(data.rig, world, obs, list(result.person_ids), data.frame_times, data.kp_xy, data.kp_vis)
    checks = physical_checks(ws, model, data.rig, result.frame_times, result.joints, result.observed, data.present,
                             result.betas, result.person_ids, views)
    for line in summary_lines(checks):
        log.warn(f"fit check: {line}")
    report = {
        "stage": "fit", "skipped": False, "body_model": model.name, "cameras": data.cameras,
        "reference": data.reference, "frame_camera": data.frame_camera, "stages": stages,
        "frames": int(len(data.frame_times)),
        "time_span_s": [float(data.frame_times[0]), float(data.frame_times[-1])],
        "persons": [{"id": int(pid), "file": ws.relative(ws.person_file(pid)),
                     "frames_observed": int(result.observed[i].sum())} for i, pid in enumerate(result.person_ids)],
        "chunks": result.chunks,
        "stage_stats": {k: v.to_dict() for k, v in result.stats.items()},
        "reprojection_px": reprojection_report(model, fitter, result),
        "views_set_aside": {"max_miss_frac": cfg.view_outlier_frac, "frames": set_aside},
        "keypoints": ({"used": True, "weight": cfg.keypoint_weight, "robust_scale_sigmas": cfg.keypoint_gamma,
                       "regressor_learned": fitter.body_regressor.learned,
                       "reprojection_px": keypoint_report(model, fitter, result, fitter.body_regressor)}
                      if fitter.kp is not None else
                      {"used": False, "why": "no keypoints/<cam>.npz" if not data.has_keypoints
                       else "keypoint_weight is 0"}),
        "hand_keypoints": ({"used": True, "weight": cfg.hand_keypoint_weight,
                            "reprojection_px": keypoint_report(model, fitter, result, fitter.hand_regressor,
                                                               hands=True)}
                           if fitter.hands else
                           {"used": False, "why": "no hand the hand model was sure of in keypoints/<cam>.npz"
                            if not data.has_hands else "hand_keypoint_weight or keypoint_weight is 0"}),
        "seconds": round(secs, 2), "threads": torch.get_num_threads(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "notes": data.notes,
        "checks": checks,
    }
    write_json(report_path, report)
    manifest.record(inputs, settings, written + [report_path], {"persons": len(written), "seconds": secs}, secs)
    return report


def physical_checks(ws, model, rig, times_t, joints_ptj3, observed_pt, seen_cpt, betas_pb, person_ids,
                    views=()) -> dict:
    """fitting.checks on fitted bodies (arrays as check_fit takes them; the floor is known where
    calibration found it; ``views``: fitting.viewcheck's findings)."""
    from mamma_kit.core.calibfile import read_calibration

    floor = False
    if ws.calibration.is_file():
        floor = read_calibration(ws.calibration)[1]["rig"].get("world", {}).get("source") == "floor"
    return check_fit(joints_ptj3, observed_pt, seen_cpt, times_t, rig, floor, rest_heights(model, betas_pb),
                     list(person_ids), views=views)


def report_path(ws) -> Path:
    return ws.smplx_dir / REPORT_NAME
