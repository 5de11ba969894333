"""Calibration on exactly known corner detections (projected, with pixel noise, no video):
every lens model, fixed intrinsics, unsynchronised cameras, a strongly distorting rig,
inverted boards, and the Schur-complement bundle adjustment against scipy's."""

from __future__ import annotations

import numpy as np
import pytest

from mamma_kit.calibration.board import BoardSpec, load_board_spec
from mamma_kit.calibration.detect import BoardFinder, Detections
from mamma_kit.calibration.intrinsics import calibrate_camera, projection_difference
from mamma_kit.calibration.solve import Settings, calibrate
from mamma_kit.core.camera import Camera, Rig
from mamma_kit.core.clock import ClockModel
from mamma_kit.evaluation.calibration import compare
from mamma_kit.synth.board import corner_visibility, plan_session

from test_calibration import look_at

LENSES = {
    "radtan": [-0.30, 0.11, 0.0007, -0.0004, -0.02],
    "rational": [0.6, -0.3, 0.0005, 0.0003, -0.05, 0.9, -0.2, -0.08],
    "fisheye": [0.04, -0.015, 0.004, -0.001],
}


def ring(model: str, n=4, radius=3.0, height=1.5, size=(960, 720), f=520.0, seed=0) -> Rig:
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.2
        C = np.array([radius * np.cos(a), radius * np.sin(a), height])
        R = look_at(C, [0, 0, 0.7])
        w, h = size
        K = np.array([[f * (1 + 0.02 * rng.standard_normal()), 0, w / 2 + rng.uniform(-10, 10)],
                      [0, f * (1 + 0.02 * rng.standard_normal()), h / 2 + rng.uniform(-10, 10)], [0, 0, 1]])
        cams.append(Camera(f"cam{i}", size, K, LENSES[model], model, R, -R @ C))
    return Rig(cams)


def detections(rig: Rig, spec: BoardSpec, traj, clocks: dict, fps=8.0, noise=0.08, seed=0) -> dict[str, Detections]:
    """What a detector would report: visible corners of the true board, projected, + noise."""
    rng = np.random.default_rng(seed)
    out = {}
    for cam in rig:
        t_cam = np.arange(int(traj.duration * fps)) / fps
        R_wb, t_wb = traj.pose(clocks[cam.name].to_ref(t_cam))
        xy = np.full((len(t_cam), spec.n_corners, 2), np.nan)
        for f in range(len(t_cam)):
            if corner_visibility(cam, R_wb[f], t_wb[f], spec, max_angle_deg=70) < 0.3:
                continue
            p = cam.project(spec.corners_b3 @ R_wb[f].T + t_wb[f])
            w, h = cam.size
            inside = (p[:, 0] > 2) & (p[:, 0] < w - 3) & (p[:, 1] > 2) & (p[:, 1] < h - 3)
            xy[f, inside] = p[inside] + rng.normal(0, noise, (inside.sum(), 2))
        out[cam.name] = Detections(cam.name, f"{cam.name}.mp4", cam.size, t_cam, xy, np.zeros(len(t_cam), int))
    return out


def assert_lens_within(true: Camera, est: Camera, det: Detections, res, p95: float, worst: float) -> None:
    seen = det.xy_fn2[res.views].reshape(-1, 2)
    _, diff = projection_difference(true, est, region_xy=seen[np.isfinite(seen[:, 0])])
    d = diff[np.isfinite(diff)]
    assert len(d) > 0.6 * len(diff), len(d) / len(diff)
    assert np.percentile(d, 95) < p95 and d.max() < worst, (np.percentile(d, 95), d.max())


@pytest.mark.parametrize("model", ["radtan", "rational", "fisheye"])
def test_intrinsics_recover_every_lens_model(model):
    rig = ring(model, n=1)
    spec = load_board_spec("charuco-a3")
    traj = plan_session(rig, spec, seed=2, duration_s=40, n_closeups=24, floor_pose=False, closeup_fill=(0.3, 0.75))
    det = detections(rig, spec, traj, {"cam0": ClockModel()})["cam0"]
    res = calibrate_camera(det, spec, model, max_views=40)
    true = rig["cam0"]
    est = res.camera
    assert abs(est.K[0, 0] / true.K[0, 0] - 1) < 0.002
    assert np.linalg.norm(est.K[:2, 2] - true.K[:2, 2]) < 1.5
    # the whole lens: rays mapped within a fraction of a pixel wherever the board was seen.
    # The bound is statistical: with 0.08 px corner noise and 40 views, the 95th percentile
    # ranged 0.05-0.22 px over 8 noise seeds for every model (radtan worst), so 0.3 px
    assert_lens_within(true, est, det, res, p95=0.3, worst=0.45)
    assert res.std["fx"] > 0 and res.rms_px < 0.15


@pytest.fixture(scope="module")
def fisheye_rig_data():
    rig = ring("fisheye", n=4)
    spec = load_board_spec("charuco-a1")
    clocks = {"cam0": ClockModel(), "cam1": ClockModel(offset=0.62), "cam2": ClockModel(offset=-0.91),
              "cam3": ClockModel(offset=1.73, rate=30e-6)}
    traj = plan_session(rig, spec, seed=4, duration_s=100, n_closeups=6, tremor_m=0.0003)
    return rig, spec, clocks, detections(rig, spec, traj, clocks, fps=6.0)


def test_unsynchronised_fisheye_rig_end_to_end(fisheye_rig_data):
    """Still boards matched across cameras whose clocks differ by up to 1.7 s; world pinned
    by the floor boards; every unknown at once (intrinsics, extrinsics, boards)."""
    rig, spec, clocks, dets = fisheye_rig_data
    res = calibrate({n: f"{n}.mp4" for n in rig.names}, spec, Settings(model="fisheye", cross_validation=False),
                    detections=dets, progress=False)
    assert res.diagnostics["world"]["source"] == "floor" and res.diagnostics["world"]["floor_boards"] == 3
    for n, clk in clocks.items():
        assert abs(res.camera_diagnostics[n]["board_clock_offset_s"] - clk.offset) < 0.15
    ev = compare(res.rig, rig, align="none")["worst"]
    assert ev["focal_pct"] < 0.1 and ev["principal_point_px"] < 1.0
    # a wide lens (f = 520 px): 0.1 deg is 0.9 px, the principal point's own uncertainty here
    assert ev["rotation_deg"] < 0.1 and ev["center_mm"] < 3.0
    assert res.diagnostics["rms_px"] < 0.12


def test_fixed_intrinsics_stay_fixed(fisheye_rig_data):
    rig, spec, clocks, dets = fisheye_rig_data
    known = Rig([c.copy(R=np.eye(3), t=np.zeros(3)) for c in rig])
    res = calibrate({n: f"{n}.mp4" for n in rig.names}, spec, Settings(model="fisheye", cross_validation=False),
                    intrinsics=known, detections=dets, progress=False)
    for c in rig:
        assert np.allclose(res.rig[c.name].K, c.K) and np.allclose(res.rig[c.name].dist, c.dist)
        assert res.camera_diagnostics[c.name]["intrinsics_fixed"]
    ev = compare(res.rig, rig, align="none")["worst"]
    assert ev["rotation_deg"] < 0.05 and ev["center_mm"] < 2.0


def test_schur_bundle_adjustment_matches_scipy(fisheye_rig_data):
    """Our LM/Schur solver and scipy's least_squares (trf, lsmr, jac_sparsity) reach the
    same optimum on the same problem."""
    from mamma_kit.calibration import bundle as B

    rig, spec, clocks, dets = fisheye_rig_data
    captured = {}
    orig = B.bundle_adjust

    def spy(*a, **k):
        captured["args"], captured["kw"] = a, k
        return orig(*a, **k)

    import mamma_kit.calibration.solve as S

    S.bundle_adjust, saved = spy, S.bundle_adjust
    try:
        calibrate({n: f"{n}.mp4" for n in list(rig.names)[:2]}, spec,
                  Settings(model="fisheye", cross_validation=False, floor=False),
                  detections={n: dets[n] for n in list(rig.names)[:2]}, progress=False)
    finally:
        S.bundle_adjust = saved
    a, k = captured["args"], dict(captured["kw"])
    ours = orig(*a, **k, rounds=1)
    theirs = orig(*a, **k, rounds=1, solver="scipy")
    assert abs(ours.rms_px - theirs.rms_px) < 1e-3
    for n in ours.cameras:
        assert np.allclose(ours.cameras[n].K, theirs.cameras[n].K, rtol=1e-4, atol=1e-2)
        assert np.linalg.norm(ours.cameras[n].center - theirs.cameras[n].center) < 1e-4


def test_inverted_board_is_found_when_the_spec_says_so():
    from mamma_kit.synth.board import BoardRenderer, facing_rotation

    spec = BoardSpec(5, 7, 0.04, 0.03, "DICT_4X4_50", inverted=True, name="inv")
    cam = Camera("c", (480, 360), [[420, 0, 240], [0, 420, 180], [0, 0, 1]], [-0.1, 0.02, 0, 0, 0])
    R = facing_rotation(np.array([0.2, -0.15, -1.0]), up=np.array([0, -1.0, 0]), roll=0.3)
    t = np.array([0, 0, 0.45]) - R @ spec.center_b3
    import cv2

    grey = cv2.cvtColor(BoardRenderer(cam, spec, supersample=2).render([(R, t)], np.random.default_rng(0), 1.0),
                        cv2.COLOR_RGB2GRAY)
    xy, n_markers = BoardFinder(spec).detect(grey)
    ok = np.isfinite(xy[:, 0])
    assert ok.sum() == spec.n_corners and n_markers == 17
    truth = cam.project(spec.corners_b3 @ R.T + t)
    assert np.sqrt(np.mean(np.sum((xy - truth) ** 2, 1))) < 0.15
    # the same print read as a normal board: nothing
    xy2, _ = BoardFinder(spec.with_(inverted=False)).detect(grey)
    assert np.isfinite(xy2[:, 0]).sum() == 0
