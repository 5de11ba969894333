"""One projection: core's Camera.project (core.camera.project_points) is the reference; the
bundle adjustment's vectorised path and the fit's torch path are fast paths tested against
it for every lens model each of them handles, and the undistortions against the lens."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mamma_kit.calibration.association import Event
from mamma_kit.calibration.board import load_board_spec
from mamma_kit.calibration.bundle import bundle_adjust
from mamma_kit.calibration.lens import undistort_exact
from mamma_kit.core.camera import Camera, Rig, rodrigues
from mamma_kit.core.lens import FIT_MODELS, LENSES, PIXEL_LENS_MODELS, SOLVABLE_MODELS
from mamma_kit.fitting.projection import RigTensors

# every lens model and coefficient count a camera may have
FORMS = [(m, n) for m in LENSES for n in LENSES[m].n_coeffs]
NORMALISED_FORMS = [(m, n) for m, n in FORMS if m not in PIXEL_LENS_MODELS]
FIT_FORMS = [(m, n) for m, n in FORMS if m in FIT_MODELS]
TOL_PX = 1e-9


def _coeffs(model: str, n: int, rng: np.random.Generator, K_33: np.ndarray) -> np.ndarray:
    """Random coefficients of a real-looking (monotonic over the image) lens."""
    if model == "fisheye":
        return rng.uniform(-0.05, 0.05, n)
    if model == "vicon_radial":
        f = K_33[0, 0]
        pp = K_33[:2, 2] + rng.uniform(-5, 5, 2)
        return np.r_[pp, rng.uniform(-0.1, 0.1) / f ** 2, rng.uniform(-0.02, 0.02) / f ** 4, 0.0]
    scale = np.array([0.2, 0.05, 0.002, 0.002, 0.02, 0.05, 0.02, 0.01, 1e-3, 1e-3, 1e-3, 1e-3])
    return rng.uniform(-1, 1, n) * scale[:n]


def _camera(name: str, model: str, n: int, rng: np.random.Generator, R_33=np.eye(3), t_3=np.zeros(3),
            skew: float = 0.0) -> Camera:
    f = rng.uniform(500, 1000)
    K = np.array([[f, skew, 320 + rng.uniform(-10, 10)], [0, f * rng.uniform(0.98, 1.02), 240 + rng.uniform(-10, 10)],
                  [0, 0, 1.0]])
    return Camera(name, (640, 480), K, _coeffs(model, n, rng, K), model, R_33, t_3)


def _points_in_view(cam: Camera, rng: np.random.Generator, n: int, half_fov: float = 0.35) -> np.ndarray:
    """World points (n, 3) in front of ``cam``, within its field of view."""
    z = rng.uniform(1.0, 5.0, n)
    xy = rng.uniform(-half_fov, half_fov, (n, 2)) * z[:, None]
    Xc = np.c_[xy, z]
    return (Xc - cam.t) @ cam.R


def test_the_lens_table_is_consistent():
    for name, m in LENSES.items():
        assert m.name == name and len(m.coeff_names) == max(m.n_coeffs)
        assert not m.solvable or m.solve_coeffs in m.n_coeffs
    assert set(SOLVABLE_MODELS) <= set(LENSES) and set(FIT_MODELS) <= set(LENSES)
    # the shorter forms are prefixes: radtan's names begin rational's (OpenCV's order)
    assert LENSES["rational"].coeff_names[:5] == LENSES["radtan"].coeff_names


# ---- the bundle's vectorised projection --------------------------------------------------
def _bundle_setup(model: str, n: int, seed: int):
    """Three cameras in the reference camera's frame (cam0 = identity) around a board that
    is in front of all of them, six board poses, their corners projected (+ noise)."""
    rng = np.random.default_rng(seed)
    spec = load_board_spec("charuco-a3")
    target = np.array([0.0, 0.0, 2.5])
    cams = {}
    for i, yaw in enumerate([0.0, 0.35, -0.3]):
        R = rodrigues([rng.normal(0, 0.03), yaw, rng.normal(0, 0.03)])
        t = target - R @ target  # looks at the target from 2.5 m
        cams[f"cam{i}"] = _camera(f"cam{i}", model, n, rng, R, t)
    ev_R, ev_t, events = [], [], []
    for _ in range(6):
        R = rodrigues(rng.normal(0, 0.25, 3))
        t = target + rng.normal(0, 0.1, 3) - R @ spec.center_b3
        X = spec.corners_b3 @ R.T + t
        obs = {}
        for name, cam in cams.items():
            xy = cam.project(X)
            inside = np.isfinite(xy).all(1) & (xy >= 0).all(1) & (xy < cam.size).all(1)
            obs[name] = np.where(inside[:, None], xy + rng.normal(0, 0.2, xy.shape), np.nan)
        ev_R.append(R)
        ev_t.append(t)
        events.append(Event("hold", obs, 0.0))
    return cams, spec, events, np.array(ev_R), np.array(ev_t)


@pytest.mark.parametrize("model,n", FORMS)
@pytest.mark.parametrize("max_iter", [0, 3])
def test_bundle_projection_matches_camera(model, n, max_iter):
    """The bundle's residuals are its projection minus the observations: at the returned
    cameras and board poses they equal Camera.project's (before and after LM moved them).
    vicon_radial with fixed intrinsics (calibrate never refines a Vicon lens)."""
    cams, spec, events, ev_R, ev_t = _bundle_setup(model, n, seed=n + 13 * len(model))
    fixed = set(cams) if model in PIXEL_LENS_MODELS else set()
    with np.errstate(over="ignore", invalid="ignore"):  # the finite-difference probes of fixed Vicon terms
        res = bundle_adjust(cams, fixed, "cam0", spec, events, ev_R, ev_t, rounds=1, max_iter=max_iter)
    names = res.names
    X = np.einsum("mij,mj->mi", res.event_R[res.obs_evt], spec.corners_b3[res.obs_corner]) + res.event_t[res.obs_evt]
    ref = np.empty_like(res.obs_xy)
    for c, name in enumerate(names):
        m = res.obs_cam == c
        ref[m] = res.cameras[name].project(X[m])
    bundle_xy = res.obs_xy + res.residual
    assert np.isfinite(ref).all()
    assert np.abs(bundle_xy - ref).max() < TOL_PX


# ---- the fit's torch projection ------------------------------------------------------------
def _fit_rig(model: str, n: int, seed: int) -> Rig:
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(3):
        R = rodrigues(rng.normal(0, 0.4, 3))
        cams.append(_camera(f"c{i}", model, n, rng, R, rng.normal(0, 0.5, 3), skew=rng.uniform(-1, 1)))
    return Rig(cams)


@pytest.mark.parametrize("model,n", FIT_FORMS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fit_projection_and_jacobian_match_camera(model, n, seed):
    """RigTensors.project = Camera.project within 1e-9 px; project_jacobian's closed form =
    autograd of RigTensors.project (to round-off) and = central differences of Camera.project."""
    rig = _fit_rig(model, n, seed)
    rng = np.random.default_rng(100 + seed)
    X_cn3 = np.stack([_points_in_view(c, rng, 60) for c in rig])  # each camera's own points
    rt = RigTensors.from_rig(rig)
    ref = np.stack([c.project(X_cn3[i]) for i, c in enumerate(rig)])
    X = torch.as_tensor(X_cn3).requires_grad_(True)
    uv, valid = rt.project(X)
    assert bool(valid.all()) and np.isfinite(ref).all()
    assert np.abs(uv.detach().numpy() - ref).max() < TOL_PX

    uv_j, J, valid_j = rt.project_jacobian(X.detach())
    assert np.abs(uv_j.numpy() - ref).max() < TOL_PX and bool(valid_j.all())
    # autograd: each pixel depends on its own point only, so d sum(u) / d X is d u / d X per point
    J_auto = torch.stack([torch.autograd.grad(uv[..., i].sum(), X, retain_graph=True)[0] for i in range(2)], -2)
    scale = float(J_auto.abs().max())
    assert float((J - J_auto).abs().max()) < 1e-10 * scale
    h = 1e-6
    J_fd = np.stack([(np.stack([c.project(X_cn3[i] + h * e) for i, c in enumerate(rig)])
                      - np.stack([c.project(X_cn3[i] - h * e) for i, c in enumerate(rig)])) / (2 * h)
                     for e in np.eye(3)], -1)
    assert np.abs(J.numpy() - J_fd).max() < 1e-6 * scale


def test_fit_refuses_the_models_it_does_not_implement():
    from mamma_kit.core.errors import UserError

    rng = np.random.default_rng(0)
    for model in set(LENSES) - set(FIT_MODELS):
        rig = Rig([_camera("c", model, LENSES[model].n_coeffs[-1], rng)])
        with pytest.raises(UserError, match=f"not {model}"):
            RigTensors.from_rig(rig)


# ---- the undistortion ----------------------------------------------------------------------
@pytest.mark.parametrize("model,n", FORMS)
@pytest.mark.parametrize("seed", [0, 1])
def test_undistortions_invert_the_lens(model, n, seed):
    """Camera.pixels_to_lens (core's Newton from the distorted point) and undistort_exact
    (core's Newton from OpenCV's start) both invert Camera.lens_to_pixels over the image, and
    agree with each other to ~1e-12 in normalised coordinates; a zero fisheye is still
    equidistant."""
    rng = np.random.default_rng(seed)
    cam = _camera("c", model, n, rng)
    if seed == 1 and model == "fisheye":
        cam = cam.copy(dist=np.zeros(4))
    xy = rng.uniform([0, 0], [639, 479], (400, 2))
    xn = cam.pixels_to_lens(xy)
    assert np.abs(cam.lens_to_pixels(xn) - xy).max() < TOL_PX
    if model in PIXEL_LENS_MODELS:  # undistort_exact is for the normalised-coordinate models
        with pytest.raises(ValueError, match="pixels_to_lens"):
            undistort_exact(cam, xy)
        return
    xn_cv = undistort_exact(cam, xy)
    assert np.abs(cam.lens_to_pixels(xn_cv) - xy).max() < TOL_PX
    assert np.abs(xn_cv - xn).max() < 1e-12
