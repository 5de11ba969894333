"""Lens models: the one table of what each model is, and its numpy lens functions.

Every place that lists lens models, their coefficient counts or coefficient names reads
:data:`LENSES` (Camera's validation, calibrate's choice of model, the bundle's and the
intrinsics' standard-deviation names, the fit's supported models). The models follow OpenCV:

- ``radtan``   : k1, k2, p1, p2[, k3]                  (cv2.projectPoints, 0, 4 or 5 coeffs)
- ``rational`` : k1, k2, p1, p2, k3, k4, k5, k6[, s1..s4] (8 or 12 coeffs)
- ``fisheye``  : k1, k2, k3, k4                         (cv2.fisheye, equidistant)
- ``vicon_radial`` : pp_x, pp_y, rad_1, rad_2, rad_3 (pixels; Vicon's VICON_RADIAL2, the
  MAMMA release's ``vicon_radial_2``): a pinhole-projected pixel u (through K) is recorded
  at pp + (u - pp)(1 + rad_1 d^2 + rad_2 d^4 + rad_3 d^6), d^2 = |u - pp|^2 in pixels. It
  acts on pixels, not on normalised coordinates, so only :func:`lens_to_pixels` /
  :func:`pixels_to_lens` (and Camera's methods built on them) apply it;
  :func:`distort_normalized` refuses it.

Normalised coordinates are (x/z, y/z) of camera-frame points; ``xy_n2`` arrays are (..., 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.core.errors import UserError


@dataclass(frozen=True)
class LensModel:
    """One lens model.

    n_coeffs: the coefficient counts a camera of this model may have. coeff_names: the
    coefficients in order (the longest form; shorter forms are its prefixes). on_pixels:
    defined on pixels (needs K) rather than on normalised coordinates. solve_coeffs: how many
    coefficients `calibrate` solves (0: calibrate cannot solve this model). fit: the fit's
    torch projection (fitting/projection.py) implements it.
    """

    name: str
    n_coeffs: tuple[int, ...]
    coeff_names: tuple[str, ...]
    on_pixels: bool = False
    solve_coeffs: int = 0
    fit: bool = False

    @property
    def solvable(self) -> bool:
        return self.solve_coeffs > 0


_RADTAN = ("k1", "k2", "p1", "p2", "k3")
LENSES: dict[str, LensModel] = {m.name: m for m in (
    LensModel("radtan", (0, 4, 5), _RADTAN, solve_coeffs=5, fit=True),
    # OpenCV's rational order: radtan's five, then the denominator k4..k6, then thin prism s1..s4
    LensModel("rational", (8, 12), _RADTAN + ("k4", "k5", "k6", "s1", "s2", "s3", "s4"), solve_coeffs=8, fit=True),
    LensModel("fisheye", (4,), ("k1", "k2", "k3", "k4"), solve_coeffs=4, fit=True),
    LensModel("vicon_radial", (5,), ("pp_x", "pp_y", "rad_1", "rad_2", "rad_3"), on_pixels=True),
)}
PIXEL_LENS_MODELS = tuple(n for n, m in LENSES.items() if m.on_pixels)  # need K: not on normalised coordinates
SOLVABLE_MODELS = tuple(n for n, m in LENSES.items() if m.solvable)  # `calibrate --model` choices
FIT_MODELS = tuple(n for n, m in LENSES.items() if m.fit)  # the fit's torch projection


def require_solvable(model: str) -> None:
    """UserError unless `calibrate` can solve the lens ``model``."""
    if model not in SOLVABLE_MODELS:
        raise UserError(f"unknown lens model '{model}'",
                        f"use --model {', '.join(SOLVABLE_MODELS[:-1])} or {SOLVABLE_MODELS[-1]}")


def coefficient_names(model: str, n: int) -> list[str]:
    """Names of the first ``n`` coefficients of ``model`` (n = a camera's len(dist))."""
    return list(LENSES[model].coeff_names[:n])


# ---- normalised-coordinate models (radtan, rational, fisheye) --------------------------------
def distort_normalized(xy_n2: np.ndarray, model: str, dist: np.ndarray) -> np.ndarray:
    """Apply a lens model to normalised image coordinates (x/z, y/z): (..., 2) -> (..., 2)."""
    if LENSES[model].on_pixels:
        raise ValueError(f"the {model} lens model acts on pixels: use Camera.project / Camera.unproject")
    xy = np.asarray(xy_n2, float)
    x, y = xy[..., 0], xy[..., 1]
    d = np.zeros(12)
    d[: len(dist)] = dist
    if model == "fisheye":
        k1, k2, k3, k4 = d[:4]
        r = np.sqrt(x * x + y * y)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        # theta_d / r -> 1 as r -> 0
        scale = np.where(r > 1e-12, theta_d / np.where(r > 1e-12, r, 1.0), 1.0)
        return np.stack([x * scale, y * scale], -1)
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = d
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1 + k1 * r2 + k2 * r4 + k3 * r6) / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r4
    return np.stack([xd, yd], -1)


def undistort_normalized(xyd_n2: np.ndarray, model: str, dist: np.ndarray, iters: int = 30,
                         start_n2: np.ndarray | None = None) -> np.ndarray:
    """Invert :func:`distort_normalized`: (..., 2) distorted -> undistorted normalised
    coordinates, by Newton's method with a numeric 2x2 Jacobian (the one undistortion of the
    package: calibration/lens.py's ``undistort_exact`` gives it OpenCV's start).

    ``start_n2``: the first guess (default: the distorted coordinates themselves). Vectorised
    over points; converges to ~1e-14 for the distortion of real lenses (~1e-11 px).
    """
    xyd = np.asarray(xyd_n2, float)
    if model != "fisheye" and not np.any(dist):  # (a zero fisheye is still equidistant)
        return xyd.copy()
    xy = xyd.copy() if start_n2 is None else np.array(start_n2, float)
    eps = 1e-7
    for _ in range(iters):
        f = distort_normalized(xy, model, dist) - xyd
        # 1e-14 in normalised units is ~1e-11 px: far below anything that matters
        if np.nanmax(np.abs(f), initial=0.0) < 1e-14:
            break
        fx = (distort_normalized(xy + [eps, 0], model, dist) - xyd - f) / eps
        fy = (distort_normalized(xy + [0, eps], model, dist) - xyd - f) / eps
        a, c = fx[..., 0], fx[..., 1]
        b, dd = fy[..., 0], fy[..., 1]
        det = a * dd - b * c
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        dx = (dd * f[..., 0] - b * f[..., 1]) / det
        dy = (-c * f[..., 0] + a * f[..., 1]) / det
        step = np.stack([dx, dy], -1)
        # damp huge steps far outside the valid lens region
        norm = np.linalg.norm(step, axis=-1, keepdims=True)
        step = np.where(norm > 0.5, step * (0.5 / np.maximum(norm, 1e-12)), step)
        xy = xy - step
    return xy


# ---- pixel models (vicon_radial) ---------------------------------------------------------
def vicon_distort_pixels(u_n2: np.ndarray, coeffs_5: np.ndarray) -> np.ndarray:
    """Pinhole pixels (..., 2) -> recorded pixels under Vicon's radial model
    [pp_x, pp_y, rad_1, rad_2, rad_3]."""
    c = np.asarray(coeffs_5, float)
    d = np.asarray(u_n2, float) - c[:2]
    r2 = np.sum(d * d, -1, keepdims=True)
    return c[:2] + d * (1 + r2 * (c[2] + r2 * (c[3] + r2 * c[4])))


def vicon_undistort_pixels(v_n2: np.ndarray, coeffs_5: np.ndarray, iters: int = 50) -> np.ndarray:
    """Recorded pixels (..., 2) -> pinhole pixels: the radius r with r (1 + rad_1 r^2 +
    rad_2 r^4 + rad_3 r^6) = |v - pp| by Newton's method (to ~1e-12 px), along v - pp;
    NaN where no radius on the lens's monotonic part gives |v - pp|."""
    c = np.asarray(coeffs_5, float)
    d = np.asarray(v_n2, float) - c[:2]
    rv = np.linalg.norm(d, axis=-1)
    k1, k2, k3 = c[2:]
    r = rv.copy()
    for _ in range(iters):
        r2 = r * r
        f = r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) - rv
        if np.nanmax(np.abs(f), initial=0.0) < 1e-12:
            break
        df = 1 + r2 * (3 * k1 + r2 * (5 * k2 + 7 * k3 * r2))
        r = r - f / np.where(np.abs(df) < 1e-12, 1e-12, df)
    r2 = r * r
    # beyond the lens's fold (where the radial map stops growing) no pinhole pixel maps here
    bad = np.abs(r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) - rv) > 1e-6
    bad |= 1 + r2 * (3 * k1 + r2 * (5 * k2 + 7 * k3 * r2)) <= 0
    scale = np.where(rv > 1e-15, r / np.where(rv > 1e-15, rv, 1.0), 1.0)
    return np.where(bad[..., None], np.nan, c[:2] + d * scale[..., None])


# ---- the whole lens: normalised coordinates <-> recorded pixels --------------------------
def normalized_to_pixels(xy_n2: np.ndarray, K_33: np.ndarray) -> np.ndarray:
    """Normalised coordinates (..., 2) -> pixels (..., 2) through K (with its skew)."""
    x, y = xy_n2[..., 0], xy_n2[..., 1]
    u = K_33[0, 0] * x + K_33[0, 1] * y + K_33[0, 2]
    v = K_33[1, 1] * y + K_33[1, 2]
    return np.stack([u, v], -1)


def pixels_to_normalized(xy_n2: np.ndarray, K_33: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) -> normalised coordinates (..., 2): the inverse of K only."""
    xy = np.asarray(xy_n2, float)
    y = (xy[..., 1] - K_33[1, 2]) / K_33[1, 1]
    x = (xy[..., 0] - K_33[0, 2] - K_33[0, 1] * y) / K_33[0, 0]
    return np.stack([x, y], -1)


def lens_to_pixels(xy_n2: np.ndarray, K_33: np.ndarray, dist: np.ndarray, model: str) -> np.ndarray:
    """Undistorted normalised coordinates (..., 2) -> recorded (distorted) pixels (..., 2)."""
    if LENSES[model].on_pixels:  # vicon_radial: K first, then the radial map on pixels
        return vicon_distort_pixels(normalized_to_pixels(xy_n2, K_33), dist)
    return normalized_to_pixels(distort_normalized(xy_n2, model, dist), K_33)


def pixels_to_lens(xy_n2: np.ndarray, K_33: np.ndarray, dist: np.ndarray, model: str) -> np.ndarray:
    """Recorded pixels (..., 2) -> undistorted normalised coordinates (..., 2), the inverse
    of :func:`lens_to_pixels` (NaN where a vicon_radial pixel lies beyond the lens's fold)."""
    if LENSES[model].on_pixels:
        return pixels_to_normalized(vicon_undistort_pixels(xy_n2, dist), K_33)
    return undistort_normalized(pixels_to_normalized(xy_n2, K_33), model, dist)
