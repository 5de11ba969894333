"""Round trips between every pair of calibration formats preserve projections (1e-6 px)."""

import itertools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mamma_kit.calibration.formats import (FORMATS, SUPPORTED_MODELS, convert, infer_format, read_rig,
                                           rig_projection_difference, write_rig)
from mamma_kit.core.camera import Camera, Rig, rodrigues
from mamma_kit.core.errors import UserError

PAIRS = list(itertools.permutations([f for f in FORMATS if "radtan" in SUPPORTED_MODELS[f]], 2))
FILENAMES = {"mamma-kit": "calibration.toml", "mamma-yaml": "calib.yaml", "easymocap": "emc/intri.yml",
             "anipose": "anipose.toml", "caliscope": "camera_array.toml", "opencv-json": "calib.json",
             "vicon-xcp": "calib.xcp"}


@st.composite
def rigs(draw, model="radtan"):
    n = draw(st.integers(1, 4))
    seed = draw(st.integers(0, 10_000))
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        w, h = draw(st.sampled_from([(640, 480), (1920, 1080), (1080, 1920), (3840, 2160)]))
        f = rng.uniform(0.6, 1.6) * w
        K = np.array([[f, 0, w / 2 + rng.uniform(-20, 20)], [0, f * rng.uniform(0.99, 1.01), h / 2 + rng.uniform(-20, 20)],
                      [0, 0, 1]])
        if model == "radtan":
            d = np.r_[rng.uniform(-0.3, 0.3, 2), rng.uniform(-0.005, 0.005, 2), rng.uniform(-0.1, 0.1)]
        elif model == "rational":
            d = np.r_[rng.uniform(-0.3, 0.3, 2), rng.uniform(-0.005, 0.005, 2), rng.uniform(-0.1, 0.1, 4)]
        elif model == "vicon_radial":  # [pp_x, pp_y, rad_1, rad_2, rad_3], radial in pixels
            r2 = (0.5 * max(w, h)) ** 2
            d = np.r_[K[0, 2] + rng.uniform(-10, 10), K[1, 2] + rng.uniform(-10, 10), rng.uniform(-0.1, 0.1) / r2,
                      rng.uniform(-0.02, 0.02) / r2 ** 2, rng.uniform(-0.01, 0.01) / r2 ** 3]
        else:
            d = rng.uniform(-0.05, 0.05, 4)
        R = rodrigues(rng.uniform(-np.pi, np.pi, 3) * rng.uniform(0, 1))
        t = rng.uniform(-5, 5, 3)
        cams.append(Camera(f"cam{i}", (w, h), K, d, model, R, t))
    return Rig(cams)


def _points_in_front(rig: Rig, rng) -> np.ndarray:
    """World points in front of each camera that project inside its image."""
    pts = []
    for c in rig:
        half = 0.5 * np.array(c.size) / np.diag(c.K)[:2]
        xy = rng.uniform(-half, half, (200, 2))
        depth = rng.uniform(1, 8, 200)
        Xc = np.c_[xy, np.ones(200)] * depth[:, None]
        X = (Xc - c.t) @ c.R
        uv = c.project(X)
        inside = np.isfinite(uv).all(1) & (uv >= 0).all(1) & (uv < c.size).all(1)
        pts.append(X[inside])
    return np.concatenate(pts)


def _roundtrip(rig: Rig, a: str, b: str, tmp: Path) -> Rig:
    pa, pb = tmp / "a" / FILENAMES[a], tmp / "b" / FILENAMES[b]
    write_rig(rig, pa, a)
    convert(pa, pb, a, b)
    back = tmp / "c" / FILENAMES[a]
    convert(pb, back, b, a)
    return read_rig(back, a)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rig=rigs("radtan"))
@pytest.mark.parametrize("a,b", PAIRS)
def test_roundtrip_every_pair_radtan(tmp_path_factory, a, b, rig):
    tmp = tmp_path_factory.mktemp("rt")
    back = _roundtrip(rig, a, b, tmp)
    assert len(back) == len(rig)
    X = _points_in_front(rig, np.random.default_rng(0))
    assert rig_projection_difference(rig, back, X) < 1e-6
    for c0, c1 in zip(rig, back):
        assert c0.size == c1.size


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rig=rigs("rational"), data=st.data())
def test_roundtrip_rational_where_supported(tmp_path_factory, rig, data):
    fmts = [f for f in FORMATS if "rational" in SUPPORTED_MODELS[f]]
    a, b = data.draw(st.sampled_from(list(itertools.permutations(fmts, 2))))
    back = _roundtrip(rig, a, b, tmp_path_factory.mktemp("rr"))
    assert rig_projection_difference(rig, back, _points_in_front(rig, np.random.default_rng(1))) < 1e-6


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rig=rigs("fisheye"), data=st.data())
def test_roundtrip_fisheye_where_supported(tmp_path_factory, rig, data):
    fmts = [f for f in FORMATS if "fisheye" in SUPPORTED_MODELS[f]]
    a, b = data.draw(st.sampled_from(list(itertools.permutations(fmts, 2))))
    back = _roundtrip(rig, a, b, tmp_path_factory.mktemp("rf"))
    assert rig_projection_difference(rig, back, _points_in_front(rig, np.random.default_rng(2))) < 1e-6


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rig=rigs("vicon_radial"), data=st.data())
def test_roundtrip_vicon_radial_where_supported(tmp_path_factory, rig, data):
    fmts = [f for f in FORMATS if "vicon_radial" in SUPPORTED_MODELS[f]]
    assert set(fmts) == {"mamma-kit", "mamma-yaml", "vicon-xcp"}
    a, b = data.draw(st.sampled_from(list(itertools.permutations(fmts, 2))))
    back = _roundtrip(rig, a, b, tmp_path_factory.mktemp("rv"))
    assert [c.model for c in back] == ["vicon_radial"] * len(rig)
    assert rig_projection_difference(rig, back, _points_in_front(rig, np.random.default_rng(3))) < 1e-6


def test_unsupported_model_is_refused(tmp_path):
    rig = Rig([Camera("c", (640, 480), np.eye(3) * [500, 500, 1] + [[0, 0, 320], [0, 0, 240], [0, 0, 0]],
                      np.zeros(4), "fisheye")])
    with pytest.raises(UserError, match="cannot hold the fisheye"):
        write_rig(rig, tmp_path / "camera_array.toml", "caliscope")


def test_format_inference(tmp_path, ring_rig):
    for fmt, name in FILENAMES.items():
        p = tmp_path / fmt / name
        rig = ring_rig
        if "radtan" not in SUPPORTED_MODELS[fmt]:  # .xcp holds Vicon's lens only
            rig = Rig([c.copy(model="vicon_radial", dist=[c.K[0, 2], c.K[1, 2], 0, 0, 0]) for c in ring_rig])
        write_rig(rig, p, fmt)
        assert infer_format(p) == fmt
    assert infer_format(tmp_path / "x" / "camera_array.toml", for_writing=True) == "caliscope"


def test_caliscope_keeps_rotation_count(tmp_path, ring_rig):
    rig = Rig([c.copy(meta={"rotation_count": -1 if i == 1 else 0}) for i, c in enumerate(ring_rig)])
    write_rig(rig, tmp_path / "camera_array.toml")
    back = read_rig(tmp_path / "camera_array.toml")
    assert [c.meta["rotation_count"] for c in back] == [0, -1, 0, 0]
    assert back.names == ["cam_0", "cam_1", "cam_2", "cam_3"]


def test_convert_renames_and_scales(tmp_path, ring_rig):
    src = tmp_path / "calibration.toml"
    write_rig(ring_rig, src)
    rig_mm = tmp_path / "mm.json"
    # pretend a file in millimetres, then bring it back with --scale
    write_rig(Rig([c.copy(t=c.t * 1000) for c in ring_rig]), rig_mm)
    out = tmp_path / "out.toml"
    rig, _, _ = convert(rig_mm, out, None, "mamma-kit", names=["a", "b", "c", "d"], scale=0.001)
    back = read_rig(out)
    assert back.names == ["a", "b", "c", "d"]
    assert np.allclose(back.centers(), ring_rig.centers())


def test_mamma_yaml_pose_is_camera_to_world(tmp_path, ring_rig):
    import yaml

    p = tmp_path / "c.yaml"
    write_rig(ring_rig, p, "mamma-yaml")
    d = yaml.safe_load(p.read_text())["cameras"]["cam0"]
    assert np.allclose(d["translation"], ring_rig[0].center)
