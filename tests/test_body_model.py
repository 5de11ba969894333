"""Body model: loader, LBS against smplx.SMPLX (open body and a synthetic SMPL-X file), errors."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch

from mamma_kit.body import skeleton as sk
from mamma_kit.body.lbs import UPRIGHT_ORIENT, axis_angle_to_matrix, pose_mesh, pose_mesh_np, pose_restricted
from mamma_kit.body.model import OPEN_BODY_FILE, load_body_model, read_body_model_file
from mamma_kit.core.errors import UserError


@pytest.fixture(scope="module")
def body():
    return load_body_model("open")


def random_params(B: int, seed: int, expression: bool = False, dtype=torch.float32) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    r = lambda n, s=0.5: (s * torch.randn(B, n, generator=g)).to(dtype)  # noqa: E731
    p = {"betas": r(16, 1.0), "global_orient": r(3, 1.0), "body_pose": r(63), "left_hand_pose": r(45),
         "right_hand_pose": r(45), "jaw_pose": r(3, 0.2), "leye_pose": r(3, 0.2), "reye_pose": r(3, 0.2),
         "transl": r(3, 1.0)}
    if expression:
        p["expression"] = r(10, 1.0)
    return p


def smplx_reference(path, extra_ids, params, B):
    smplx = pytest.importorskip("smplx", reason="smplx (optional extra, MPI licence) is not installed")
    m = smplx.SMPLX(str(path), ext="npz", num_betas=16, use_pca=False, flat_hand_mean=True,
                    num_expression_coeffs=10, dtype=torch.float64)
    m.vertex_joint_selector.extra_joints_idxs = torch.as_tensor(extra_ids)
    kw = {k: v.double() for k, v in params.items()}
    kw.setdefault("expression", torch.zeros(B, 10, dtype=torch.float64))
    return m, kw


def test_open_body_layout(body):
    assert body.num_joints == 55 and body.joint_names == sk.JOINT_NAMES
    assert np.array_equal(body.parents.numpy(), sk.PARENTS)
    assert body.num_betas == 16 and body.exprdirs is None and body.posedirs is None
    assert body.v_template.dtype == torch.float32 and body.v_template.shape == (body.num_vertices, 3)
    assert body.J_regressor.shape == (55, body.num_vertices)
    # skinning: the sparse table holds every weight and rows sum to one
    dense = torch.zeros(body.num_vertices, 55).scatter_add_(1, body.skin_idx, body.skin_w)
    assert torch.allclose(dense, body.weights_dense, atol=1e-6)
    assert torch.allclose(body.weights_dense.sum(1), torch.ones(body.num_vertices), atol=1e-5)
    # canonical frame: Y up, facing +Z, left side at +X
    J = body.J_template.numpy()
    assert J[sk.JOINT_NAMES.index("head"), 1] > J[0, 1] + 0.4
    assert J[sk.JOINT_NAMES.index("left_hip"), 0] > 0 > J[sk.JOINT_NAMES.index("right_hip"), 0]
    nose = body.np.v_template[body.extra_joint_ids[0]]
    assert nose[2] > J[sk.JOINT_NAMES.index("head"), 2] + 0.05
    assert 1.5 < np.ptp(body.np.v_template[:, 1]) < 1.9  # an adult's height in metres
    assert OPEN_BODY_FILE.stat().st_size < 5e6


def test_restricted_lbs_matches_smplx_on_open_body(body):
    B = 6
    p = random_params(B, seed=1)
    sm, kw = smplx_reference(OPEN_BODY_FILE, body.extra_joint_ids, p, B)
    with torch.no_grad():
        ref = sm(**kw)
    v, j = pose_restricted(body, p)
    assert v.shape == (B, 512, 3) and j.shape == (B, 55, 3)
    assert (v.double() - ref.vertices[:, body.landmark_ids]).abs().max() < 1e-5
    assert (j.double() - ref.joints[:, :55]).abs().max() < 1e-5
    vf, _ = pose_mesh(body, p)
    assert (vf.double() - ref.vertices).abs().max() < 1e-5
    # the 21 extra keypoints are mesh vertices
    assert torch.equal(ref.joints[:, 55:], ref.vertices[:, body.extra_joint_ids])


def test_gradients_match_smplx(body):
    B = 3
    p = random_params(B, seed=2)
    sm, kw = smplx_reference(OPEN_BODY_FILE, body.extra_joint_ids, p, B)
    for d in (p, kw):
        for t in d.values():
            t.requires_grad_(True)
    v, j = pose_restricted(body, p)
    (v.sum() + (j ** 2).sum()).backward()
    ref = sm(**kw)
    (ref.vertices[:, body.landmark_ids].sum() + (ref.joints[:, :55] ** 2).sum()).backward()
    for k in ("betas", "global_orient", "body_pose", "left_hand_pose", "transl"):
        g, gr = p[k].grad.double(), kw[k].grad
        assert (g - gr).abs().max() < 1e-3 * max(1.0, gr.abs().max().item()), k


def test_broadcast_people_frames_and_paths_agree(body):
    P, T = 2, 5
    flat = random_params(P * T, seed=3)
    betas = torch.randn(P, 16, generator=torch.Generator().manual_seed(4))
    flat["betas"] = betas.repeat_interleave(T, 0)
    v_flat, j_flat = pose_restricted(body, flat)
    grouped = {k: t.reshape(P, T, -1) for k, t in flat.items()}
    grouped["betas"] = betas[:, None]  # per person, shared over frames
    v, j = pose_restricted(body, grouped)
    assert v.shape == (P, T, 512, 3)
    assert torch.allclose(v.reshape(P * T, 512, 3), v_flat, atol=2e-6)
    assert torch.allclose(j.reshape(P * T, 55, 3), j_flat, atol=2e-6)
    vs, _ = pose_restricted(body, grouped, sparse=True)
    assert torch.allclose(vs, v, atol=2e-6)
    vn, jn = pose_mesh_np(body, {k: t.detach().numpy() for k, t in flat.items()}, chunk=4)
    assert np.allclose(vn[:, body.landmark_ids], v_flat.detach().numpy(), atol=2e-6)


def test_rodrigues_and_world_orientation(body):
    aa = torch.tensor([[0.0, 0.0, 0.0], [1e-6, 0, 0], [0.3, -1.2, 2.0]], dtype=torch.float64, requires_grad=True)
    R = axis_angle_to_matrix(aa)
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(3, 3, 3), atol=1e-12)
    assert torch.allclose(torch.det(R), torch.ones(3, dtype=torch.float64))
    R.sum().backward()
    assert torch.isfinite(aa.grad).all()
    # UPRIGHT_ORIENT turns the canonical Y-up body Z-up: head above pelvis along world Z
    _, j = pose_restricted(body, {"global_orient": UPRIGHT_ORIENT[None]})
    up = j[0, sk.JOINT_NAMES.index("head")] - j[0, 0]
    assert up[2] > 0.4 and abs(up[1]) < 0.1


def _synthetic_smplx(path, V=900, seed=0, with_object=True):
    """Random arrays in the SMPL-X .npz key layout (400 shape/expression columns, posedirs)."""
    rng = np.random.default_rng(seed)
    v = rng.normal(0, 0.3, (V, 3))
    v[:, 1] *= 3
    Wt = np.zeros((V, 55))
    for k in range(4):  # four random joints per vertex
        Wt[np.arange(V), rng.integers(0, 55, V)] += rng.random(V)
    Wt /= Wt.sum(1, keepdims=True)
    Jr = np.zeros((55, V))
    for j in range(55):
        ids = rng.choice(V, 20, replace=False)
        Jr[j, ids] = rng.random(20)
    Jr /= Jr.sum(1, keepdims=True)
    arrays = dict(
        v_template=v, f=rng.integers(0, V, (2 * V, 3)).astype(np.uint32), weights=Wt, J_regressor=Jr,
        kintree_table=np.stack([np.where(sk.PARENTS < 0, 4294967295, sk.PARENTS), np.arange(55)]).astype(np.int64),
        shapedirs=rng.normal(0, 0.01, (V, 3, 400)), posedirs=rng.normal(0, 0.005, (V, 3, 486)),
        hands_componentsl=np.eye(45), hands_componentsr=np.eye(45),
        hands_meanl=rng.normal(0, 0.2, 45), hands_meanr=rng.normal(0, 0.2, 45),
        lmk_faces_idx=np.zeros(0, np.int64), lmk_bary_coords=np.zeros((0, 3)))
    if with_object:  # like the real files' joint2num / part2num dicts: never touched by our loader
        arrays["joint2num"] = np.array({"pelvis": 0}, dtype=object)
    np.savez(path, **arrays)
    return arrays


def test_synthetic_smplx_file_matches_smplx(tmp_path):
    path = tmp_path / "SMPLX_FEMALE.npz"
    _synthetic_smplx(path)
    m = load_body_model(path)
    assert m.gender == "female" and m.name == "SMPLX_FEMALE" and not m.is_open_body
    assert m.posedirs is not None and m.num_expression == 10 and len(m.landmarks) == 512
    assert m.landmarks.source == "fps"
    B = 4
    p = random_params(B, seed=5, expression=True)
    extra = np.arange(21)
    sm, kw = smplx_reference(path, extra, p, B)
    with torch.no_grad():
        ref = sm(**kw)
    v, j = pose_restricted(m, p)
    assert (v.double() - ref.vertices[:, m.landmark_ids]).abs().max() < 1e-5
    assert (j.double() - ref.joints[:, :55]).abs().max() < 1e-5
    vf, _ = pose_mesh(m, p)
    assert (vf.double() - ref.vertices).abs().max() < 1e-5
    # folder spec picks the gender's file
    assert load_body_model(tmp_path, gender="female").sha256 == m.sha256


def test_loader_errors(tmp_path):
    with pytest.raises(UserError, match="not found"):
        load_body_model(tmp_path / "nope.npz")
    with pytest.raises(UserError, match="no SMPLX_NEUTRAL.npz"):
        load_body_model(tmp_path)
    pkl = tmp_path / "SMPLX_NEUTRAL.pkl"
    pkl.write_bytes(pickle.dumps({"v_template": np.zeros((3, 3))}))
    with pytest.raises(UserError, match="pickled"):
        load_body_model(pkl)
    disguised = tmp_path / "model.npz"
    disguised.write_bytes(pickle.dumps({"a": 1}))
    with pytest.raises(UserError, match="pickled"):
        load_body_model(disguised)
    partial = tmp_path / "partial.npz"
    np.savez(partial, v_template=np.zeros((10, 3)), f=np.zeros((1, 3), np.int64))
    with pytest.raises(UserError, match="lacks the SMPL-X keys"):
        load_body_model(partial)
    arrays = _synthetic_smplx(tmp_path / "ok.npz", V=600, with_object=False)
    arrays["kintree_table"] = arrays["kintree_table"][:, :52]
    np.savez(tmp_path / "smplh.npz", **arrays)
    with pytest.raises(UserError, match="not an SMPL-X model"):
        read_body_model_file(tmp_path / "smplh.npz")
    arrays = _synthetic_smplx(tmp_path / "ok2.npz", V=600, with_object=False)
    arrays["weights"] = arrays["weights"][:, :50]
    np.savez(tmp_path / "badw.npz", **arrays)
    with pytest.raises(UserError, match="weights have shape"):
        read_body_model_file(tmp_path / "badw.npz")
    trunc = tmp_path / "trunc.npz"
    trunc.write_bytes(OPEN_BODY_FILE.read_bytes()[:100000])
    with pytest.raises(UserError):
        load_body_model(trunc)
