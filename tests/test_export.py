"""Exports read back by other tools' readers: glTF (pygltflib), BVH (parsed here), C3D (ezc3d),
TRC, AMASS (smplx); each puts the body where the fit's own LBS does."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from mamma_kit.body.lbs import UPRIGHT_ORIENT, pose_mesh_np, pose_restricted
from mamma_kit.body.model import load_body_model
from mamma_kit.core.smplxfile import SmplxResult, write_smplx_result
from mamma_kit.core.workspace import Workspace

Y_UP_TO_Z_UP = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # the inverse of export's Z_UP_TO_Y_UP
FPS = 30.0


@pytest.fixture(scope="module")
def body():
    return load_body_model("open")


def _result(body, seed: int, times: np.ndarray) -> SmplxResult:
    g = torch.Generator().manual_seed(seed)
    T = len(times)

    def r(n, s):
        return (s * torch.randn(T, n, generator=g)).double()

    p = {"betas": 0.8 * torch.randn(16, generator=g).double(), "body_pose": r(63, 0.3), "jaw_pose": r(3, 0.1),
         "leye_pose": r(3, 0.1), "reye_pose": r(3, 0.1), "left_hand_pose": r(45, 0.3), "right_hand_pose": r(45, 0.3),
         "global_orient": torch.as_tensor(UPRIGHT_ORIENT).expand(T, 3) + r(3, 0.2),
         "transl": r(3, 0.5) + torch.tensor([seed * 0.8, 0.0, 0.9], dtype=torch.float64)}
    with torch.no_grad():
        _, joints = pose_restricted(body, {k: v.float() for k, v in p.items()})
    return SmplxResult.from_params(p, joints.double().numpy(), times, FPS, body.name, body.sha256)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory, body):
    """A workspace with two fitted people: person 0 over 12 frames, person 3 starting later with a gap."""
    from mamma_kit.core.calibfile import write_calibration
    from mamma_kit.core.camera import Camera, Rig

    root = tmp_path_factory.mktemp("ws")
    ws = Workspace(root)
    ws.smplx_dir.mkdir()
    t = 10.0 + np.arange(12) / FPS
    people = {0: _result(body, 0, t), 3: _result(body, 3, np.r_[t[4:7], t[10:12], t[11] + 3 / FPS])}
    for k, r in people.items():
        write_smplx_result(ws.person_file(k), r)
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    R = Rotation.from_euler("x", -100, degrees=True).as_matrix()
    cams = [Camera(name=f"cam{i}", size=(640, 480), K=K, dist=np.zeros(5), R=R @ Rotation.from_euler(
        "z", 90 * i, degrees=True).as_matrix(), t=np.array([0.0, 1.0, 4.0])) for i in range(2)]
    write_calibration(ws.calibration, Rig(cams))
    return ws, people, Rig(cams)


# ---- glTF ------------------------------------------------------------------------------------
def test_gltf_skeleton_puts_every_joint_where_the_fit_does(fitted, body, tmp_path, cli):
    from mamma_kit.export.gltf_read import GltfScene

    ws, people, rig = fitted
    res = cli("export", ws.root, "--format", "gltf", "--json")
    assert res.code == 0, res
    scene = GltfScene(ws.export_dir / "capture.glb")
    gl, names = scene.gltf, scene.node_id
    t0 = min(r.frame_times[0] for r in people.values())
    for k, r in people.items():
        ids = [names[f"person{k}/{j}"] for j in body.joint_names]
        for f in range(r.num_frames):
            W = scene.world(r.frame_times[f] - t0)
            xyz = np.array([W[i][:3, 3] for i in ids]) @ Y_UP_TO_Z_UP.T
            assert np.abs(xyz - r.joints[f]).max() < 1e-3  # metres: under a millimetre
    # person 3 is hidden (scale 0) before their first frame and in their gap, shown in their frames
    p3 = names["person3/pelvis"]
    gap = people[3].frame_times[2] + 1.5 / FPS
    for t, shown in ((people[0].frame_times[0], False), (people[3].frame_times[0], True), (gap, False)):
        assert (np.abs(scene.world(t - t0)[p3][:3, :3]).sum() > 0.5) == shown
    # the cameras sit at their calibrated centres, looking along their optical axes
    for cam in rig:
        W = scene.world(0.0)[names[f"camera/{cam.name}"]]
        assert np.allclose(W[:3, 3] @ Y_UP_TO_Z_UP.T, -cam.R.T @ cam.t, atol=1e-5)
        assert np.allclose(-W[:3, 2] @ Y_UP_TO_Z_UP.T, cam.R[2], atol=1e-5)
    assert gl.cameras[0].perspective.yfov == pytest.approx(2 * np.arctan(240 / 500))


def test_gltf_skinned_mesh_follows_the_fit(fitted, body, cli):
    """The mesh skinned by glTF's rule (joint world x inverse bind x rest vertex) against the
    fit's LBS: the open body's six weights per vertex become four."""
    from mamma_kit.export.gltf_read import GltfScene

    ws, people, _ = fitted
    if not (ws.export_dir / "capture.glb").is_file():
        cli("export", ws.root)
    scene = GltfScene(ws.export_dir / "capture.glb")
    gl = scene.gltf
    node = next(n for n in gl.nodes if n.name == "person0/body")
    skin, prim = gl.skins[node.skin], gl.meshes[node.mesh].primitives[0]
    ibm = scene.array(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    v = np.c_[scene.array(prim.attributes.POSITION), np.ones(body.num_vertices)]
    J, Wt = scene.array(prim.attributes.JOINTS_0), scene.array(prim.attributes.WEIGHTS_0)
    r = people[0]
    f = 5
    W = scene.world(r.frame_times[f] - r.frame_times[0])
    M = np.stack([W[j] @ ibm[i] for i, j in enumerate(skin.joints)])  # (J, 4, 4)
    skinned = np.einsum("vk,vkab,vb->va", Wt, M[J], v)[:, :3] @ Y_UP_TO_Z_UP.T
    ref, _ = pose_mesh_np(body, r.params(f))
    err = np.linalg.norm(skinned - ref[0], axis=1)
    assert np.median(err) < 1e-4 and err.max() < 0.02  # metres


# ---- BVH -------------------------------------------------------------------------------------
def _read_bvh(path):
    text = path.read_text().split("MOTION")
    names, parents, offsets, stack = [], [], [], []
    for line in text[0].splitlines():
        w = line.split()
        if w and w[0] in ("ROOT", "JOINT"):
            names.append(w[1])
            parents.append(stack[-1] if stack else -1)
        elif w and w[0] == "End":
            names.append(None)
            parents.append(stack[-1])
        elif w and w[0] == "OFFSET":
            offsets.append([float(x) for x in w[1:]])
        elif w and w[0] == "{":
            stack.append(len(names) - 1)
        elif w and w[0] == "}":
            stack.pop()
    lines = text[1].strip().splitlines()
    frames, ftime = int(lines[0].split()[1]), float(lines[1].split()[2])
    values = np.array([[float(x) for x in ln.split()] for ln in lines[2:]])
    return names, np.array(parents), np.array(offsets), frames, ftime, values


def test_bvh_holds_every_joint_and_frame_and_its_angles_pose_the_fit(fitted, body, tmp_path, cli):
    ws, people, _ = fitted
    out = tmp_path / "p0.bvh"
    assert cli("export", ws.root, "--format", "bvh", "--person", 0, "--out", out).code == 0
    names, parents, offsets, frames, ftime, values = _read_bvh(out)
    joints = [i for i, n in enumerate(names) if n is not None]
    assert len(joints) == 55 and sorted(n for n in names if n) == sorted(body.joint_names)
    r = people[0]
    assert frames == r.num_frames == len(values) and ftime == pytest.approx(1 / FPS)
    for f in (0, 7, 11):
        row = values[f]
        pos = {}
        Rw = {}
        c = 3
        for i in joints:  # channels in file order: root position, then ZXY per joint
            R = Rotation.from_euler("ZXY", row[c:c + 3], degrees=True).as_matrix()
            c += 3
            if parents[i] < 0:
                Rw[i], pos[i] = R, row[:3] + offsets[i]
            else:
                Rw[i] = Rw[parents[i]] @ R
                pos[i] = pos[parents[i]] + Rw[parents[i]] @ offsets[i]
        xyz = np.array([pos[names.index(n)] for n in body.joint_names])
        assert np.abs(xyz / 100 @ Y_UP_TO_Z_UP.T - r.joints[f]).max() < 1e-3


def test_bvh_fills_a_persons_gap_on_the_frame_grid(fitted, tmp_path, cli):
    ws, people, _ = fitted
    out = tmp_path / "p3.bvh"
    res = cli("export", ws.root, "--format", "bvh", "--person", 3, "--out", out, "--json")
    assert res.code == 0, res
    _, _, _, frames, _, values = _read_bvh(out)
    assert frames == 11 and np.array_equal(values[3], values[2])  # fitted: grid frames 0-2, 6-7 and 10


# ---- markers: C3D and TRC ---------------------------------------------------------------------
def test_c3d_and_trc_hold_the_markers_on_the_fitted_surface(fitted, body, tmp_path, cli):
    import ezc3d

    from mamma_kit.export.markers import marker_positions, marker_vertices

    ws, people, _ = fitted
    names, ids = marker_vertices(body)
    assert len(names) == len(set(ids.tolist())) == 46 and {"LASI", "RKNE", "C7", "LHEE"} <= set(names)
    res = cli("export", ws.root, "--format", "c3d", "--out", tmp_path)
    assert res.code == 0, res
    r = people[3]
    c = ezc3d.c3d(str(tmp_path / "person_3.c3d"))
    pts = c["data"]["points"]
    assert c["parameters"]["POINT"]["LABELS"]["value"] == names
    assert c["parameters"]["POINT"]["RATE"]["value"][0] == FPS and pts.shape == (4, 46, 11)
    _, xyz = marker_positions(body, r)
    grid = [0, 1, 2, 6, 7, 10]
    assert np.abs(pts[:3, :, grid].transpose(2, 1, 0) / 1000 - xyz).max() < 1e-6
    assert np.isnan(pts[:3, :, [3, 4, 5, 8, 9]]).all()  # the gaps: invalid markers
    v, _ = pose_mesh_np(body, r.params(slice(0, 1)))
    assert np.abs(xyz[0] - v[0, ids]).max() < 1e-5

    assert cli("export", ws.root, "--format", "trc", "--person", 3, "--out", tmp_path / "p3.trc").code == 0
    lines = (tmp_path / "p3.trc").read_text().splitlines()
    assert lines[2].split("\t")[:5] == ["30", "30", "11", "46", "mm"]
    assert lines[3].split("\t")[2] == names[0]
    row = lines[6].split("\t")
    assert row[0] == "1" and np.allclose(np.array(row[2:5], float) / 1000 @ Y_UP_TO_Z_UP.T, xyz[0, 0], atol=1e-6)
    assert lines[9].split("\t")[2] == ""  # a frame of the gap


# ---- AMASS -----------------------------------------------------------------------------------
def test_amass_npz_poses_the_same_joints_in_smplx(fitted, tmp_path, cli):
    smplx = pytest.importorskip("smplx", reason="smplx (optional extra, MPI licence) is not installed")
    from mamma_kit.body.model import OPEN_BODY_FILE

    ws, people, _ = fitted
    assert cli("export", ws.root, "--format", "amass", "--out", tmp_path).code == 0
    d = np.load(tmp_path / "person_0.npz")
    assert d["poses"].shape == (12, 165) and float(d["mocap_framerate"]) == FPS and str(d["surface_model_type"]) == "smplx"
    m = smplx.SMPLX(str(OPEN_BODY_FILE), ext="npz", num_betas=16, use_pca=False, flat_hand_mean=True, dtype=torch.float64)
    P = torch.as_tensor(d["poses"])
    out = m(betas=torch.as_tensor(d["betas"])[None].expand(12, 16), global_orient=P[:, :3], body_pose=P[:, 3:66],
            jaw_pose=P[:, 66:69], leye_pose=P[:, 69:72], reye_pose=P[:, 72:75], left_hand_pose=P[:, 75:120],
            right_hand_pose=P[:, 120:165], transl=torch.as_tensor(d["trans"]), expression=torch.zeros(12, 10,
                                                                                                        dtype=torch.float64))
    assert (out.joints[:, :55].numpy() - people[0].joints).__abs__().max() < 1e-3


# ---- bad input -------------------------------------------------------------------------------
def test_export_refuses_what_it_cannot_do_in_one_line(fitted, tmp_path, cli):
    ws, _, _ = fitted
    empty = tmp_path / "empty"
    empty.mkdir()
    for args, words in (((empty,), "no fitted people"), ((ws.root, "--person", 7), "no fitted person 7"),
                        ((ws.root, "--format", "fbx"), "unknown export format"),
                        ((ws.root, "--format", "bvh", "--out", tmp_path / "one.bvh"), "one file per person")):
        res = cli("export", *args)
        assert res.code == 2 and words in res.err, res
        assert "Traceback" not in res.err and len(res.err.strip().splitlines()) <= 2
