"""Landmark set (FPS, determinism, density, file definitions) and the proxy mesh + signed distance."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from mamma_kit.body import skeleton as sk
from mamma_kit.body.landmarks import landmark_set_fps, load_landmark_definition
from mamma_kit.body.model import load_body_model
from mamma_kit.body.proxy import pose_proxy, signed_distance
from mamma_kit.core.errors import UserError


@pytest.fixture(scope="module")
def body():
    return load_body_model("open")


def test_landmarks_deterministic_and_baked(body):
    a = landmark_set_fps(body.np.v_template, body.np.weights_dense, body.vertex_part)
    b = landmark_set_fps(body.np.v_template, body.np.weights_dense, body.vertex_part)
    assert np.array_equal(a.ids, b.ids) and len(a.ids) == 512 and len(np.unique(a.ids)) == 512
    # the baked set is what the loader's FPS produces: nothing drifted since the bake
    assert np.array_equal(a.ids, body.landmark_ids) and np.array_equal(a.part, body.landmark_parts)


def test_landmark_density_hands_head_above_torso(body):
    V, F = body.np.v_template.astype(np.float64), body.np.faces
    area = trimesh.Trimesh(V, F, process=False).area_faces
    face_part = body.vertex_part[F[:, 0]]
    lm_part = body.vertex_part[body.landmark_ids]

    def density(parts):
        ids = [sk.PART_NAMES.index(p) for p in parts]
        return np.isin(lm_part, ids).sum() / area[np.isin(face_part, ids)].sum()

    torso = density(["torso", "pelvis"])
    assert density(["left_hand"]) > 4 * torso and density(["right_hand"]) > 4 * torso
    assert density(["head"]) > 1.5 * torso
    assert density(["left_foot", "right_foot"]) > 1.5 * torso
    counts = {n: int(body.landmarks.mask(n).sum()) for n in sk.LANDMARK_PART_NAMES}
    assert sum(counts.values()) == 512 and min(counts.values()) >= 10, counts


def test_landmark_definition_from_files(body, tmp_path):
    rng = np.random.default_rng(0)
    ids = rng.choice(body.num_vertices, 512, replace=False)
    onehot = torch.zeros(512, body.num_vertices)
    onehot[torch.arange(512), torch.as_tensor(ids)] = 1.0
    torch.save(onehot, tmp_path / "verts_512.pt")
    groups = np.array_split(np.arange(512), 7)
    keys = ["body", "left_hand", "right_hand", "left_feet", "right_feet", "left_head", "right_head"]
    np.savez(tmp_path / "parts.npz", **dict(zip(keys, groups)))
    ls = load_landmark_definition(tmp_path / "verts_512.pt", body.num_vertices, tmp_path / "parts.npz")
    assert np.array_equal(ls.ids, ids)
    assert np.all(ls.part[groups[3]] == sk.LANDMARK_PART_NAMES.index("left_foot"))
    assert np.all(ls.part[groups[6]] == sk.LANDMARK_PART_NAMES.index("head"))
    m2 = body.with_landmarks(ls)
    assert np.array_equal(m2.restricted().ids, ids) and body.landmark_ids is not m2.landmark_ids
    torch.save(torch.zeros(512, 10475), tmp_path / "smplx_def.pt")
    with pytest.raises(UserError, match="10475-vertex body"):
        load_landmark_definition(tmp_path / "smplx_def.pt", body.num_vertices, vertex_part=body.vertex_part)
    (tmp_path / "evil.pt").write_bytes(b"not a tensor")
    with pytest.raises(UserError, match="not a plain torch tensor"):
        load_landmark_definition(tmp_path / "evil.pt", body.num_vertices, vertex_part=body.vertex_part)


def test_proxy_closed_subset_and_close(body):
    px = body.proxy
    V = body.np.v_template.astype(np.float64)
    assert 1000 < len(px.vertex_ids) < 4000 and len(np.unique(px.vertex_ids)) == len(px.vertex_ids)
    tm = trimesh.Trimesh(V[px.vertex_ids], px.faces, process=False)
    assert px.watertight and tm.is_watertight and tm.is_winding_consistent and tm.volume > 0
    # close to the full skin: compare volumes and distances of the skin's vertices to the proxy
    full = trimesh.Trimesh(V, body.np.faces, process=False)
    skin = max(full.split(only_watertight=False), key=lambda c: len(c.faces))
    assert abs(tm.volume - skin.volume) / skin.volume < 0.05
    sample = skin.vertices[::20]
    d = np.abs(trimesh.proximity.signed_distance(tm, sample))
    assert np.percentile(d, 95) < 0.006 and d.max() < 0.03
    # full -> proxy map: nearest proxy vertex on the rest mesh
    assert px.full_to_proxy.shape == (body.num_vertices,)
    assert np.array_equal(px.vertex_ids[px.full_to_proxy[px.vertex_ids]], px.vertex_ids)


def test_signed_distance_matches_trimesh_and_gradients(body):
    px = body.proxy
    p = {"global_orient": torch.tensor([[0.2, 0.5, -0.1]]), "body_pose": 0.2 * torch.randn(1, 63,
                                                                                        generator=torch.Generator().manual_seed(0))}
    verts, _ = pose_proxy(body, p)
    V = verts[0].double().detach()
    tm = trimesh.Trimesh(V.numpy(), px.faces, process=False)
    rng = np.random.default_rng(1)
    pts = tm.sample(300, seed=2) + rng.normal(0, 0.03, (300, 3))
    ref = trimesh.proximity.signed_distance(tm, pts)  # trimesh: positive inside
    pt = torch.tensor(pts, requires_grad=True)
    sd = signed_distance(pt, V, px.faces, px.neighbours)
    assert np.abs(sd.detach().numpy() + ref).max() < 1e-5
    assert 0.2 < (sd < 0).float().mean() < 0.8
    sd_w = signed_distance(torch.tensor(pts), V, px.faces, px.neighbours, sign="winding")
    assert torch.equal(torch.sign(sd_w), torch.sign(sd.detach()))
    sd.sum().backward()
    far = sd.detach().abs() > 1e-3
    gn = pt.grad[far].norm(dim=-1)
    assert torch.allclose(gn, torch.ones_like(gn), atol=1e-6)  # |grad d| = 1 off the surface
    # gradients reach the mesh vertices too, and the pseudo-normal sign agrees almost everywhere
    Vg = V.clone().requires_grad_(True)
    signed_distance(torch.tensor(pts), Vg, px.faces, px.neighbours, sign="pseudonormal").sum().backward()
    assert torch.isfinite(Vg.grad).all() and Vg.grad.abs().sum() > 0
    sd_pn = signed_distance(torch.tensor(pts), V, px.faces, px.neighbours, sign="pseudonormal")
    assert (torch.sign(sd_pn) == torch.sign(sd.detach())).float().mean() > 0.98
    assert np.array_equal(body.vertex_parts, body.vertex_part) and len(body.part_names) == 16


def test_closed_manifold_check():
    from mamma_kit.body.proxy import is_closed_manifold, signed_volume

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    assert is_closed_manifold(f) and abs(signed_volume(v, f) - 1 / 6) < 1e-12
    assert not is_closed_manifold(f[:3])  # a hole
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]
    assert not is_closed_manifold(flipped)  # inconsistent winding
    assert signed_volume(v, f[:, ::-1]) < 0
