"""The fit's keypoint energy: the vertex -> BlazePose regressor (shipped weights, learning on a
tiny case), the regressed points' kinematics and Gauss-Newton pieces, a fit where keypoints
recover a pose that noisy landmarks alone do not, and the unchanged path without keypoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import make_ring_rig
from mamma_kit.core.clock import ClockModel


@pytest.fixture(scope="module")
def body():
    from mamma_kit.body.model import load_body_model

    return load_body_model("open")


@pytest.fixture(scope="module")
def reg(body):
    from mamma_kit.body.kp_regressor import keypoint_regressor

    return keypoint_regressor(body)


def _random_bodies(body, ids, P=1, T=4, seed=1, pose_sd=0.25, hand_sd=0.0):
    from scipy.spatial.transform import Rotation

    from mamma_kit.body.lbs import UPRIGHT_ORIENT, pose_restricted

    rng = np.random.default_rng(seed)
    go = (Rotation.from_euler("z", 2.0) * Rotation.from_rotvec(UPRIGHT_ORIENT)).as_rotvec()
    prm = {"global_orient": np.tile(go, (P, T, 1)) + rng.normal(0, 0.05, (P, T, 3)),
           "body_pose": rng.normal(0, pose_sd, (P, T, 63)),
           "transl": np.c_[rng.uniform(-0.3, 0.3, (T, 2)), np.full(T, 0.9)][None].repeat(P, 0),
           "betas": rng.normal(0, 1, (P, 1, 16)).repeat(T, 1)}
    if hand_sd > 0:  # fingers curled by a random amount, as hands are
        for k in ("left_hand_pose", "right_hand_pose"):
            prm[k] = np.abs(rng.normal(0, hand_sd, (P, T, 45))) * np.tile([0.2, 0.2, 1.0], 15)
    with torch.no_grad():
        v, J = pose_restricted(body, {k: torch.as_tensor(a, dtype=torch.float32) for k, a in prm.items()}, ids)
    return v.numpy().astype(float), J.numpy().astype(float), prm


def test_shipped_regressor_is_convex_sparse_and_for_the_open_body(body, reg):
    assert reg.learned and reg.body_sha256 == body.sha256
    assert reg.ids.shape == reg.weights.shape and reg.ids.shape[0] == 33
    assert (reg.weights >= 0).all()
    assert np.allclose(reg.weights.sum(1), 1.0, atol=1e-5)
    assert ((reg.ids >= 0) & (reg.ids < body.num_vertices)).all()
    # BlazePose's error is a few % of the box height: the learned per-point sigma says so
    assert (reg.sigma_frac > 0.003).all() and (reg.sigma_frac < 0.1).all()
    # each point stays a local combination: its support lies within 30 cm of the point (the
    # knees' support, thinned by farthest-point sampling, reaches 27 cm up the thigh and shin)
    v = body.v_template.numpy()
    X = reg.apply(v)
    for k in range(33):
        used = reg.ids[k][reg.weights[k] > 0]
        d = np.linalg.norm(v[used] - X[k], axis=1)
        assert d.max() < 0.30, (k, d.max())


def test_learning_recovers_points_from_noisy_detections_with_outliers(body):
    """A tiny case: detections = a known convex combination of the support, projected into
    ring cameras, with 0.5 % noise and 10 % gross errors; learning from the initial guess
    projects near the clean detections and much nearer than the guess."""
    from mamma_kit.body import kp_regressor as kr

    reg0 = kr.initial_regressor(body)
    rng = np.random.default_rng(3)
    W_true = np.zeros_like(reg0.weights)  # a few support vertices, off the guess by centimetres
    for k in range(33):
        W_true[k, rng.choice(reg0.weights.shape[1], 6, replace=False)] = rng.uniform(0.5, 1, 6)
    W_true /= W_true.sum(1, keepdims=True)
    truth = kr.KeypointRegressor(reg0.ids, W_true, reg0.sigma_frac)
    union = np.unique(reg0.ids)
    v, J, _ = _random_bodies(body, union, P=1, T=20, seed=5, pose_sd=0.35)
    rig = make_ring_rig(6)
    cams, cam_i, xn, scale, xy, clean, vis, hs, naive = [], [], [], [], [], [], [], [], []
    for ci, c in enumerate(rig):
        for t in range(v.shape[1]):
            X = truth.apply(v[0, t], union)
            px = c.project(X)
            h = np.ptp(c.project(v[0, t])[:, 1])
            noisy = px + rng.normal(0, 0.005 * h, px.shape)
            bad = rng.random(33) < 0.1
            noisy[bad] += rng.uniform(-0.3, 0.3, (bad.sum(), 2)) * h
            cam_i.append(ci)
            xn.append(c.pixels_to_lens(noisy))
            depth = c.to_camera(reg0.apply(v[0, t], union))[:, 2]
            scale.append(0.5 * (c.K[0, 0] + c.K[1, 1]) / (depth * h))
            xy.append(noisy)
            clean.append(px)
            vis.append(np.ones(33))
            hs.append(h)
            naive.append(px)
    det = kr.Detections(union, v[0][np.r_[[t for _ in rig for t in range(v.shape[1])]]], np.stack([c.R for c in rig]),
                        np.stack([c.t for c in rig]), [c.K for c in rig], np.array(cam_i), np.array(xn),
                        np.array(scale), np.array(xy), np.array(vis), np.array(hs), np.array(naive), list(rig),
                        np.zeros(len(cam_i), int))
    learned = kr.learn_regressor(det, body, reg0, ridge=1e-4)
    assert np.allclose(learned.weights.sum(1), 1) and (learned.weights >= 0).all()
    det.xy = np.array(clean)
    e_learned = kr.regressed_errors(learned, det, body)
    e_guess = kr.regressed_errors(reg0, det, body)
    assert np.median(e_learned) < 0.004, np.median(e_learned)  # < 0.4 % of the box height
    assert np.median(e_learned) < 0.3 * np.median(e_guess), (np.median(e_learned), np.median(e_guess))


def test_regressed_kinematics_equal_lbs_and_their_jacobians(body, reg):
    """Regressed points as per-slot virtual vertices: positions equal the regressor applied to
    body.lbs vertices; the shape Jacobian and lever arms equal finite differences."""
    from mamma_kit.body.lbs import pose_restricted
    from mamma_kit.fitting.energies import pose_dict
    from mamma_kit.fitting.kinematics import DTYPE, BodyKinematics, so3_exp

    kin = BodyKinematics(body, regressor=reg)
    g = torch.Generator().manual_seed(0)
    pose = 0.4 * torch.randn(2, 3, 55, 3, generator=g, dtype=DTYPE)
    betas = torch.randn(2, 16, generator=g, dtype=DTYPE)
    transl = torch.randn(2, 3, 3, generator=g, dtype=DTYPE)
    rot = so3_exp(pose)
    f = kin.forward(betas, rot, transl, jac=True, shape_jac=True, dtype=DTYPE)
    ids = np.unique(reg.ids)
    with torch.no_grad():
        v, _ = pose_restricted(body, pose_dict(pose.float(), transl.float(), betas.float()), ids)
    assert np.abs(f.v.numpy() - reg.apply(v.numpy().astype(float), ids)).max() < 1e-5
    db = torch.zeros_like(betas)
    db[:, 3] = 1e-5
    fd = (kin.forward(betas + db, rot, transl, dtype=DTYPE).v - f.v) / 1e-5
    assert (fd - f.Jb[..., 3]).abs().max() < 1e-6
    j = 18  # left elbow: its subtree turned by a small world rotation e moves a point by e x u
    e = torch.tensor([1e-6, 2e-6, -1e-6], dtype=DTYPE)
    rot2 = rot.clone()
    rot2[:, :, j] = so3_exp(f.G[:, :, kin.parents[j]].transpose(-1, -2) @ e) @ rot[:, :, j]
    dv = kin.forward(betas, rot2, transl, dtype=DTYPE).v - f.v
    slot = (kin.infl == j).float()  # (N, M)
    u = (f.u * slot[None, None, ..., None]).sum(-2)
    assert (dv - torch.linalg.cross(e.expand_as(u), u)).abs().max() < 1e-11
    assert dv.abs().max() > 1e-7  # the elbow moves some points


def test_keypoint_term_normal_equations_are_the_energy_gradient(body, reg):
    """The keypoint term's Gauss-Newton right-hand side is -1/2 dE/dx (translation by finite
    differences), and its IRLS normal matrix is positive semi-definite."""
    from mamma_kit.fitting.gauss_newton import GaussNewton, GNConfig, Obs, PointSet, State
    from mamma_kit.fitting.kinematics import DTYPE, BodyKinematics, so3_exp
    from mamma_kit.fitting.projection import RigTensors

    rig = make_ring_rig(3)
    kin = BodyKinematics(body)
    kin_kp = BodyKinematics(body, regressor=reg)
    v, J, prm = _random_bodies(body, np.unique(reg.ids), T=2)
    kp = np.stack([c.project(reg.apply(v, np.unique(reg.ids))) for c in rig])  # (C, 1, T, 33, 2)
    kp = kp + np.random.default_rng(0).normal(0, 3.0, kp.shape)
    C, P, T = kp.shape[:3]
    L = len(body.landmark_ids)
    lm = Obs(torch.zeros(C, P, T, L, 2), torch.ones(C, P, T, L, 2), torch.zeros(C, P, T, L))
    pts = PointSet(kin_kp, Obs(torch.as_tensor(kp, dtype=torch.float32), torch.full(kp.shape, 4.0),
                               torch.rand(C, P, T, 33, generator=torch.Generator().manual_seed(1))))
    active = tuple(range(22))
    gn = GaussNewton(kin, RigTensors.from_rig(rig), lm, GNConfig(active=active), pts)
    aa = np.concatenate([prm["global_orient"], prm["body_pose"]], -1).reshape(P, T, 22, 3)
    rot = torch.eye(3, dtype=DTYPE).repeat(P, T, 55, 1, 1)
    rot[:, :, :22] = so3_exp(torch.as_tensor(aa) + 0.05)
    st = State(torch.as_tensor(prm["betas"][:, 0]), rot, torch.as_tensor(prm["transl"]) + 0.02)
    gamma = 6.0
    f = kin.forward(st.betas, st.rot, st.transl, jac=True)
    fp = gn.point_forward(f, st, jac=True)
    _, H, g = gn.point_terms(fp, gamma, jac=True)
    zero = torch.zeros(P, T, L, 3, 3)
    ne = gn.normal_equations(f, zero, torch.zeros(P, T, L, 3), points=(fp, H, g))
    for i in range(3):
        h = 1e-4
        def E(d):
            s2 = st.clone()
            s2.transl[..., i] += d
            return gn.point_terms(gn.point_forward(kin.forward(s2.betas, s2.rot, s2.transl), s2), gamma, jac=False)
        dE = (E(h) - E(-h)) / (2 * h)  # (P, T)
        rhs = ne["rhs"].reshape(P, T, -1)[..., -3 + i]
        assert torch.allclose(rhs, -0.5 * dE, rtol=2e-3, atol=1e-3 * dE.abs().max()), (rhs, dE)
    ev = torch.linalg.eigvalsh(ne["N"])
    assert (ev > -1e-3 * ev.abs().max()).all()


def _fitdata(rig, v, kp=None, kp_vis=None, sigma=1.0, hand_xy=None, hand_vis=None):
    from mamma_kit.fitting.data import FitData, point_box_size

    xy = np.stack([c.project(v) for c in rig])
    C, P, T, L = xy.shape[:4]
    kw = {}
    if kp is not None:
        kw = {"kp_xy": kp.astype(np.float32), "kp_vis": kp_vis.astype(np.float32),
              "kp_size": point_box_size(kp).astype(np.float32)}
    if hand_xy is not None:
        kw |= {"hand_xy": hand_xy.astype(np.float32), "hand_vis": hand_vis.astype(np.float32)}
    return FitData(rig, {c.name: ClockModel() for c in rig}, "cam0", "cam0", np.arange(T) / 30.0, 30.0,
                   list(range(P)), xy.astype(np.float32), np.full(xy.shape, sigma, np.float32),
                   np.ones((C, P, T, L), np.float32), np.zeros((C, P, T, L), np.float32),
                   np.zeros((C, P, T, L), np.float32), np.ones((C, P, T), bool), **kw)


def test_keypoints_recover_a_pose_that_noisy_landmarks_do_not(body, reg):
    """Landmarks with heavy, part-correlated noise (8 % of the body's height, sigma saying 8 %)
    leave the joints far off; BlazePose-like keypoints (the regressor's points, 2 % noise)
    beside them, at keypoint_weight 1 (as much as the landmarks), bring the fit close; keypoints alone (landmarks off)
    recover the body too."""
    from mamma_kit.fitting.stages import FitConfig, Fitter

    rig = make_ring_rig(4)
    ids = np.unique(reg.ids)
    rng = np.random.default_rng(7)
    v_all, J, _ = _random_bodies(body, np.r_[body.landmark_ids, ids], T=3, seed=11, pose_sd=0.3)
    L = len(body.landmark_ids)
    v_lm, v_kp = v_all[..., :L, :], v_all[..., L:, :]
    kp = np.stack([c.project(reg.apply(v_kp, ids)) for c in rig])
    size = np.ptp(kp[..., 1], axis=-1)[..., None, None]
    kp = kp + rng.normal(0, 1, kp.shape) * 0.02 * size
    d = _fitdata(rig, v_lm, kp, np.ones(kp.shape[:-1]))
    h = np.ptp(d.xy[..., 1], axis=-1)[..., None, None]
    # a weak landmark network's error: whole body parts off together (8 %) plus 3 % per landmark
    parts = np.asarray(body.landmark_parts)
    part_off = rng.normal(0, 1, d.xy.shape[:3] + (parts.max() + 1, 2))[:, :, :, parts] * 0.08 * h
    d.xy = (d.xy + part_off + rng.normal(0, 1, d.xy.shape) * 0.03 * h).astype(np.float32)
    d.sigma = np.broadcast_to(0.08 * h, d.sigma.shape).astype(np.float32).copy()

    def mpjpe(cfg):
        r = Fitter(body, d, cfg).fit()
        return float(np.linalg.norm(r.joints[:, :, :22] - J[:, :, :22], axis=-1).mean() * 1000)

    without = mpjpe(FitConfig(stages=2, keypoint_weight=0.0))
    with_kp = mpjpe(FitConfig(stages=2, keypoint_weight=1.0))
    alone = mpjpe(FitConfig(stages=2, landmark_weight=0.0))
    default = mpjpe(FitConfig(stages=2))
    print(f"MPJPE mm: noisy landmarks {without:.1f}, + keypoints {with_kp:.1f}, keypoints alone {alone:.1f}")
    assert with_kp < 0.6 * without, (with_kp, without)
    assert alone < 60.0 and with_kp < 60.0, (alone, with_kp)
    assert default < without, (default, without)  # the default weight (0.1) helps too


def test_fit_without_keypoints_is_unchanged_and_says_so(body, tmp_path):
    """A workspace without keypoints/: the report says the keypoint term is off and why, and
    the fit equals one with keypoint_weight 0 on the same data (no keypoint code path runs)."""
    from mamma_kit.core.calibfile import write_calibration
    from mamma_kit.core.tracks import LandmarkTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.fitting.stage import fit_workspace
    from mamma_kit.fitting.data import load_fit_data
    from mamma_kit.fitting.stages import FitConfig, Fitter

    rig = make_ring_rig(3)
    v, J, _ = _random_bodies(body, body.landmark_ids, T=4, seed=2)
    ws = Workspace(tmp_path)
    write_calibration(ws.calibration, rig)
    times = np.arange(4) / 30.0
    for c in rig:
        xy = c.project(v[0])[:, None]  # (T, 1, L, 2)
        lt = LandmarkTracks.empty(c.name, c.size, times, np.array([0]), xy.shape[2])
        lt.valid[:] = True
        lt.xy[:] = xy
        lt.sigma[:] = 1.0
        lt.visibility[:] = 1.0
        lt.contact[:] = 0.0
        lt.floor_contact[:] = 0.0
        lt.save(ws.landmarks_file(c.name))
    cfg = FitConfig()
    rep = fit_workspace(ws, stages=2, config=cfg)
    assert cfg.stages == 4  # the caller's config is not changed (dataclasses.replace)
    assert rep["keypoints"] == {"used": False, "why": "no keypoints/<cam>.npz"}
    assert any("keypoint energy is off" in n for n in rep["notes"])
    assert "keypoints" not in rep["stage_stats"]["stage2"]["energy_terms"] or \
        rep["stage_stats"]["stage2"]["energy_terms"]["keypoints"]["end"] == 0.0
    d = load_fit_data(ws, n_landmarks=len(body.landmark_ids))
    assert d.kp_xy is None and not d.has_keypoints
    r1 = Fitter(body, d, FitConfig(stages=2)).fit()
    r0 = Fitter(body, d, FitConfig(stages=2, keypoint_weight=0.0)).fit()
    assert np.array_equal(r1.pose, r0.pose) and np.array_equal(r1.transl, r0.transl)
    assert np.linalg.norm(r1.joints - J, axis=-1).mean() < 0.005


def test_hand_points_place_the_hands_where_the_landmarks_do_not(body, reg):
    """The hand model's 21 points a hand (1 % of the body's height of noise) beside landmarks whose
    hands are off as a whole (5 %, with sigma saying so) and BlazePose-like keypoints (2 %): the wrists
    and fingers come out far nearer the truth than without them; where the hand model is unsure
    (flag 0) they change nothing."""
    from mamma_kit.body.kp_regressor import hand_regressor
    from mamma_kit.fitting.stages import FitConfig, Fitter

    hreg = hand_regressor(body)
    assert hreg.ids.shape == (42, 16) and (hreg.weights >= 0).all() and np.allclose(hreg.weights.sum(1), 1)
    rig = make_ring_rig(4)
    ids, hids = np.unique(reg.ids), np.unique(hreg.ids)
    rng = np.random.default_rng(3)
    L = len(body.landmark_ids)
    v_all, J, _ = _random_bodies(body, np.r_[body.landmark_ids, ids, hids], T=3, seed=4, pose_sd=0.3, hand_sd=0.6)
    v_lm, v_kp, v_h = v_all[..., :L, :], v_all[..., L:L + len(ids), :], v_all[..., L + len(ids):, :]
    kp = np.stack([c.project(reg.apply(v_kp, ids)) for c in rig])
    size = np.ptp(kp[..., 1], axis=-1)[..., None, None]
    kp = kp + rng.normal(0, 1, kp.shape) * 0.02 * size
    hxy = np.stack([c.project(hreg.apply(v_h, hids)) for c in rig])
    hxy = hxy + rng.normal(0, 1, hxy.shape) * 0.01 * size
    d = _fitdata(rig, v_lm, kp, np.ones(kp.shape[:-1]), hand_xy=hxy, hand_vis=np.ones(hxy.shape[:-1]))
    h = np.ptp(d.xy[..., 1], axis=-1)[..., None, None]
    parts = np.asarray(body.landmark_parts)
    from mamma_kit.body.skeleton import LANDMARK_PART_NAMES

    hand = np.isin(parts, [LANDMARK_PART_NAMES.index("left_hand"), LANDMARK_PART_NAMES.index("right_hand")])
    off = rng.normal(0, 1, d.xy.shape[:3] + (1, 2)) * 0.05 * h  # each view's hands off together
    d.xy = (d.xy + np.where(hand[:, None], off, 0) + rng.normal(0, 1, d.xy.shape) * 0.01 * h).astype(np.float32)
    d.sigma = np.broadcast_to(np.where(hand[:, None], 0.05, 0.01) * h, d.sigma.shape).astype(np.float32).copy()
    hand_joints = [20, 21] + list(range(25, 55))

    def err(cfg, data):
        r = Fitter(body, data, cfg).fit()
        return float(np.linalg.norm(r.joints[:, :, hand_joints] - J[:, :, hand_joints], axis=-1).mean() * 1000), r

    without, _ = err(FitConfig(stages=2, hand_keypoint_weight=0.0), d)
    with_h, r = err(FitConfig(stages=2), d)
    print(f"hands' joints mm: without hand points {without:.1f}, with {with_h:.1f}")
    assert with_h < 0.6 * without, (with_h, without)
    assert r.stats["stage2"].to_dict()["energy_terms"]["hand_keypoints"]["end"] > 0
    d.hand_vis = np.zeros_like(d.hand_vis)  # the model sure of no hand: the fit without them
    unsure, _ = err(FitConfig(stages=2), d)
    assert unsure == without
