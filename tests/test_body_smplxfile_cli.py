"""Per-person SMPL-X result files (round trip, validation) and the `mamma-kit body` commands."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from mamma_kit.body.lbs import UPRIGHT_ORIENT, pose_mesh_np
from mamma_kit.body.model import load_body_model
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_npz
from mamma_kit.core.smplxfile import POSE_KEYS, SmplxResult, read_smplx_result, write_smplx_result


def make_result(T: int, seed: int = 0, sha: str = "0" * 64) -> SmplxResult:
    rng = np.random.default_rng(seed)
    params = {k: 0.3 * rng.standard_normal((T, n)) for k, n in POSE_KEYS.items()}
    params["global_orient"][:] = UPRIGHT_ORIENT
    params["betas"] = rng.standard_normal(16)
    return SmplxResult.from_params(params, joints=rng.standard_normal((T, 55, 3)),
                                   frame_times=np.cumsum(rng.uniform(0.01, 0.05, T)), fps=30.0,
                                   body_model_name="open-anny", body_model_sha256=sha,
                                   producer={"tool": "mamma-kit", "command": "test"})


@settings(max_examples=15, deadline=None)
@given(T=st.integers(1, 12), seed=st.integers(0, 10_000))
def test_round_trip(tmp_path_factory, T, seed):
    path = tmp_path_factory.mktemp("rt") / "person_0.npz"
    r = make_result(T, seed)
    write_smplx_result(path, r)
    back = read_smplx_result(path)
    for k in ("betas", *POSE_KEYS, "joints", "frame_times"):
        assert np.array_equal(getattr(back, k), getattr(r, k)), k
    assert back.fps == 30.0 and back.body_model_name == "open-anny" and back.producer["command"] == "test"
    assert set(read_npz(path)) == {"betas", *POSE_KEYS, "joints", "frame_times", "fps", "body_model", "gender",
                                   "producer"}
    p = back.params(slice(0, T))
    assert p["body_pose"].shape == (T, 63) and p["betas"].shape == (16,)


def test_validation_errors(tmp_path):
    r = make_result(4)
    r.body_pose = r.body_pose[:, :60]
    with pytest.raises(UserError, match="body_pose has shape"):
        write_smplx_result(tmp_path / "a.npz", r)
    good = make_result(4)
    write_smplx_result(tmp_path / "good.npz", good)
    d = read_npz(tmp_path / "good.npz")
    d2 = dict(d)
    del d2["joints"]
    np.savez(tmp_path / "nojoints.npz", **d2)
    with pytest.raises(UserError, match="missing keys"):
        read_smplx_result(tmp_path / "nojoints.npz")
    d3 = dict(d)
    d3["transl"] = d3["transl"].copy()
    d3["transl"][1, 0] = np.nan
    np.savez(tmp_path / "nan.npz", **d3)
    with pytest.raises(UserError, match="NaN"):
        read_smplx_result(tmp_path / "nan.npz")
    d4 = dict(d)
    d4["frame_times"] = d4["frame_times"][::-1].copy()
    np.savez(tmp_path / "back.npz", **d4)
    with pytest.raises(UserError, match="increasing"):
        read_smplx_result(tmp_path / "back.npz")
    d5 = dict(d)
    d5["gender"] = np.array({"x": 1}, dtype=object)
    np.savez(tmp_path / "pickled.npz", **d5)
    with pytest.raises(UserError, match="pickled"):
        read_smplx_result(tmp_path / "pickled.npz")


def test_cli_body_info(cli):
    r = cli("body", "info", "--json")
    assert r.code == 0, r
    info = json.loads(r.out)
    assert info["joints"] == 55 and info["landmarks"] == 512 and info["shape_components"] == 16
    assert info["name"] == "open-anny" and len(info["sha256"]) == 64 and info["vertices"] > 10000
    r = cli("body", "info", "--body-model", "/nonexistent/SMPLX_NEUTRAL.npz")
    assert r.code == 2 and "body model not found" in r.err and "Traceback" not in r.err


def test_cli_body_export(cli, tmp_path):
    m = load_body_model("open")
    res = make_result(3, seed=7, sha=m.sha256)
    write_smplx_result(tmp_path / "person_0.npz", res)
    for suffix in (".obj", ".ply"):
        out = tmp_path / f"mesh{suffix}"
        r = cli("body", "export", tmp_path / "person_0.npz", "--frame", "2", "--out", out, "--json")
        assert r.code == 0, r
        mesh = trimesh.load(out, process=False)
        v_ref, _ = pose_mesh_np(m, res.params(2))
        assert len(mesh.faces) == m.num_faces
        assert np.abs(np.asarray(mesh.vertices) - v_ref[0]).max() < 1e-5
        # upright in the Z-up world: the body's height runs along Z
        ext = np.ptp(np.asarray(mesh.vertices), axis=0)
        assert ext[2] == ext.max() and ext[2] > 1.0 and json.loads(r.out)["frame"] == 2
    r = cli("body", "export", tmp_path / "person_0.npz", "--frame", "9", "--out", tmp_path / "x.obj")
    assert r.code == 2 and "outside 0..2" in r.err
    r = cli("body", "export", tmp_path / "person_0.npz", "--out", tmp_path / "x.stl")
    assert r.code == 2 and "use --out" in r.err
