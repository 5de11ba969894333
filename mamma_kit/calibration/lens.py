"""Lens helpers the calibration (and the synthetic board renderer) share."""

from __future__ import annotations

import cv2
import numpy as np

from mamma_kit.core.camera import Camera
from mamma_kit.core.lens import LENSES, distort_normalized, undistort_normalized


def radtan_equivalent(cam: Camera, grid: int = 40) -> tuple[Camera, float]:
    """The radtan camera (same K and pose; k1, k2, p1, p2, k3 fitted by least squares) whose
    projections come closest to ``cam``'s over its image, and the largest pixel difference
    on a grid over the image. For formats that cannot hold ``cam``'s lens model."""
    from scipy.optimize import least_squares

    w, h = cam.size
    nx, ny = grid, max(2, round(grid * h / w))
    xy = np.stack(np.meshgrid(np.linspace(0, w - 1, nx), np.linspace(0, h - 1, ny)), -1).reshape(-1, 2)
    xn = cam.pixels_to_lens(xy)
    ok = np.isfinite(xn).all(1)
    xn, xy = xn[ok], xy[ok]
    out = cam.copy(model="radtan", dist=np.zeros(5))

    def residual(d):
        return (out.normalized_to_pixels(distort_normalized(xn, "radtan", d)) - xy).ravel()

    fit = least_squares(residual, np.zeros(5), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    out = out.copy(dist=fit.x)
    worst = float(np.abs(residual(fit.x)).reshape(-1, 2).max(1).max()) if len(xy) else 0.0
    return out, worst


def undistort_exact(cam: Camera, xy_n2: np.ndarray) -> np.ndarray:
    """Distorted pixels (N, 2) -> undistorted normalised coordinates (N, 2), to ~1e-12.

    OpenCV's iterative undistortion gives the start; core's Newton undistortion (on core's
    own lens model, the one that projects) finishes it, so rendering and projection agree
    exactly. From that start a step or two converge: at most 4 are taken, since one point
    that does not converge (beyond a lens's fold) would keep every point of a rendered
    image iterating. Normalised-coordinate models only: OpenCV has no start for vicon_radial
    (it acts on pixels) and calibrate never poses boards through it; Camera.pixels_to_lens
    inverts it."""
    if LENSES[cam.model].on_pixels:
        raise ValueError(f"undistort_exact has no {cam.model} lens: use Camera.pixels_to_lens")
    xy = np.asarray(xy_n2, np.float64).reshape(-1, 2)
    xd = cam.pixels_to_normalized(xy)
    if cam.model != "fisheye" and not np.any(cam.dist):  # (a zero fisheye is still equidistant)
        return xd
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    if cam.model == "fisheye":
        x = cv2.fisheye.undistortPoints(xd.reshape(-1, 1, 2), np.eye(3), cam.dist.reshape(4), criteria=crit)
    else:
        x = cv2.undistortPoints(xd.reshape(-1, 1, 2), np.eye(3), cam.dist, None, None, None, crit)
    return undistort_normalized(xd, cam.model, cam.dist, iters=4, start_n2=x.reshape(-1, 2).astype(np.float64))
