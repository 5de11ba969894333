"""The fit's solver does only the work that changes the result: a limb's energy from the limb's
landmarks alone (the limbs re-posed after stage 2 are judged by it)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import make_ring_rig


@pytest.fixture(scope="module")
def problem():
    """Two people, six frames, three cameras: noisy landmarks of random bodies, and a state
    that is the truth in frames 0-2 and a turned, shifted body in frames 3-5."""
    from scipy.spatial.transform import Rotation

    from mamma_kit.body.lbs import UPRIGHT_ORIENT, pose_restricted
    from mamma_kit.body.model import load_body_model
    from mamma_kit.fitting.gauss_newton import Obs, State
    from mamma_kit.fitting.kinematics import DTYPE, BodyKinematics, so3_exp
    from mamma_kit.fitting.projection import RigTensors

    body = load_body_model("open")
    rig = make_ring_rig(3)
    P, T = 2, 6
    rng = np.random.default_rng(3)
    go = (Rotation.from_euler("z", 1.0) * Rotation.from_rotvec(UPRIGHT_ORIENT)).as_rotvec()
    prm = {"global_orient": np.tile(go, (P, T, 1)), "body_pose": rng.normal(0, 0.2, (P, T, 63)),
           "transl": np.c_[rng.uniform(-0.3, 0.3, (T, 2)), np.full(T, 0.9)][None].repeat(P, 0) + [[[0.6, 0, 0]], [[-0.6, 0, 0]]],
           "betas": rng.normal(0, 1, (P, 1, 16)).repeat(T, 1)}
    with torch.no_grad():
        v, _ = pose_restricted(body, {k: torch.as_tensor(a, dtype=torch.float32) for k, a in prm.items()},
                               body.landmark_ids)
    xy = np.stack([c.project(v.numpy().astype(float)) for c in rig])  # (C, P, T, L, 2)
    xy = xy + rng.normal(0, 2.0, xy.shape)
    obs = Obs(torch.as_tensor(xy, dtype=torch.float32), torch.full(xy.shape, 2.0),
              torch.ones(xy.shape[:-1]))
    aa = np.concatenate([prm["global_orient"], prm["body_pose"]], -1).reshape(P, T, 22, 3)
    aa[:, 3:] += rng.normal(0, 0.15, aa[:, 3:].shape)
    rot = torch.eye(3, dtype=DTYPE).repeat(P, T, 55, 1, 1)
    rot[:, :, :22] = so3_exp(torch.as_tensor(aa))
    transl = torch.as_tensor(prm["transl"])
    transl[:, 3:] += 0.05
    st = State(torch.as_tensor(prm["betas"][:, 0]), rot, transl)
    return BodyKinematics(body), RigTensors.from_rig(rig), obs, st


def test_a_limbs_landmarks_alone_give_the_energy_of_the_whole_body_weighted_to_the_limb(problem):
    from mamma_kit.fitting.gauss_newton import GaussNewton, GNConfig

    kin, cams, obs, st = problem
    W = kin.W.numpy()
    chain = np.flatnonzero(kin.sub[16])  # the left arm from the shoulder
    rows = np.flatnonzero(np.isin(W.argmax(1), chain))
    assert 0 < len(rows) < kin.N // 3
    weight = torch.as_tensor(np.isin(W.argmax(1), chain), dtype=torch.float32)
    cfg = GNConfig(active=(0,), gamma_start=4.0, wide_frac=0.3)
    whole = GaussNewton(kin, cams, obs, GNConfig(active=(0,), gamma_start=4.0, wide_frac=0.3, landmark_weight=weight))
    limb = GaussNewton(kin, cams, obs, cfg).landmarks(rows, kin.subset(rows))
    f_whole = kin.forward(st.betas, st.rot, st.transl)
    f_limb = limb.kin.forward(st.betas, st.rot, st.transl)
    assert torch.allclose(f_limb.v, f_whole.v[:, :, rows])
    # the robust scale spans the person's whole height, as the whole problem's does
    e_whole = whole.data_terms(f_whole.v, whole.gamma0, jac=False)
    e_limb = limb.data_terms(f_limb.v, limb.gamma0, jac=False)
    assert torch.allclose(e_limb, e_whole, rtol=1e-9), (e_limb, e_whole)
    assert kin.subset(rows) is limb.kin  # built once per limb
