"""Camera geometry against OpenCV and against itself (hypothesis)."""

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mamma_kit.core.camera import Camera, Rig, rodrigues, rotvec
from mamma_kit.core.lens import LENSES, SOLVABLE_MODELS

from conftest import make_ring_rig

coef = st.floats(-0.3, 0.3)
small = st.floats(-0.01, 0.01)


def _camera(model: str, d, rv, t, f=800.0, skew=0.0):
    K = np.array([[f, skew, 320.0], [0, f * 1.01, 240.0], [0, 0, 1]])
    return Camera("c", (640, 480), K, np.array(d, float), model, rodrigues(np.array(rv)), np.array(t))


def _points(rng, n=200):
    return rng.uniform([-1, -1, 3], [1, 1, 6], (n, 3))


@settings(max_examples=40, deadline=None)
@given(k=st.tuples(coef, coef, small, small, coef), rv=st.tuples(*[st.floats(-0.5, 0.5)] * 3))
def test_radtan_projection_matches_opencv(k, rv):
    cam = _camera("radtan", k, rv, [0.1, -0.2, 0.3])
    X = _points(np.random.default_rng(1))
    ours = cam.project(X)
    ref, _ = cv2.projectPoints(X, cam.rvec, cam.t, cam.K, cam.dist)
    assert np.abs(ours - ref.reshape(-1, 2)).max() < 1e-6


@settings(max_examples=30, deadline=None)
@given(k=st.tuples(coef, coef, small, small, coef, st.floats(0, 0.2), st.floats(0, 0.2), st.floats(0, 0.2)))
def test_rational_projection_matches_opencv(k):
    cam = _camera("rational", k, [0.1, 0.2, -0.1], [0, 0, 0.5])
    X = _points(np.random.default_rng(2))
    ref, _ = cv2.projectPoints(X, cam.rvec, cam.t, cam.K, cam.dist)
    assert np.abs(cam.project(X) - ref.reshape(-1, 2)).max() < 1e-6


@settings(max_examples=30, deadline=None)
@given(k=st.tuples(*[st.floats(-0.05, 0.05)] * 4))
def test_fisheye_projection_matches_opencv(k):
    cam = _camera("fisheye", k, [0.05, -0.1, 0.02], [0.1, 0, 0.2], f=300.0)
    X = _points(np.random.default_rng(3))
    ref, _ = cv2.fisheye.projectPoints(X[None], cam.rvec, cam.t, cam.K, cam.dist)
    assert np.abs(cam.project(X) - ref.reshape(-1, 2)).max() < 1e-6


@settings(max_examples=30, deadline=None)
@given(model=st.sampled_from(SOLVABLE_MODELS), seed=st.integers(0, 1000))
def test_unproject_inverts_project(model, seed):
    rng = np.random.default_rng(seed)
    n = LENSES[model].solve_coeffs  # the form calibrate solves
    d = rng.uniform(-0.05, 0.05, n)
    cam = _camera(model, d, rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.2, 0.2, 3))
    X = _points(rng, 100)
    xy = cam.project(X)
    depth = cam.to_camera(X)[:, 2]
    back = cam.unproject(xy, depth)
    assert np.abs(back - X).max() < 1e-8
    origin, dirs = cam.ray(xy)
    # every point lies on its ray
    v = X - origin
    perp = v - (v * dirs).sum(-1, keepdims=True) * dirs
    assert np.abs(perp).max() < 1e-8


def test_fundamental_matrix_epipolar_constraint(ring_rig):
    rng = np.random.default_rng(0)
    X = rng.uniform([-1, -1, 0], [1, 1, 2], (50, 3))
    a, b = ring_rig[0], ring_rig[1]
    F = a.fundamental_to(b)
    xa = np.c_[a.project(X), np.ones(50)]
    xb = np.c_[b.project(X), np.ones(50)]
    lines = xa @ F.T  # epipolar lines in b
    dist = np.abs((lines * xb).sum(1)) / np.linalg.norm(lines[:, :2], axis=1)
    assert dist.max() < 1e-6


def test_center_rotation_and_rig_lookup(ring_rig):
    c = ring_rig["cam2"]
    assert np.allclose(c.R @ c.center + c.t, 0)
    assert np.allclose(rodrigues(rotvec(c.R)), c.R)
    assert ring_rig.names == ["cam0", "cam1", "cam2", "cam3"]
    # rig projection looks at the ring centre: the target lands inside every image
    uv = ring_rig.project(np.array([[0, 0, 1.0]]))
    assert np.all((uv[..., 0] > 0) & (uv[..., 0] < 640) & (uv[..., 1] > 0) & (uv[..., 1] < 480))


def test_points_behind_camera_are_nan(ring_rig):
    c = ring_rig[0]
    behind = c.center + 2 * (c.center - np.array([0, 0, 1.0]))
    assert np.isnan(c.project(behind[None])).all()


def test_rig_transform_preserves_projection():
    rig = make_ring_rig()
    rng = np.random.default_rng(4)
    X = rng.uniform(-1, 1, (20, 3)) + [0, 0, 1]
    R_w = rodrigues(np.array([0.1, 0.2, 0.3]))
    t_w = np.array([0.5, -0.2, 0.1])
    s = 1.7
    moved = rig.transformed(R_w, t_w, s)
    assert np.abs(moved.project(s * X @ R_w.T + t_w) - rig.project(X)).max() < 1e-8


def test_triangulate_points_recovers_points_seen_by_two_or_more_cameras(ring_rig):
    from mamma_kit.core.camera import triangulate_points

    rng = np.random.default_rng(3)
    X = rng.uniform([-1, -1, 0], [1, 1, 2], (50, 3))
    xy = np.stack([cam.project(X) for cam in ring_rig])
    w = np.ones(xy.shape[:2])
    w[1:, -5:] = 0  # the last five seen by one camera only
    Xt = triangulate_points(ring_rig, xy, w)
    np.testing.assert_allclose(Xt[:-5], X[:-5], atol=1e-8)
    assert np.isnan(Xt[-5:]).all()
