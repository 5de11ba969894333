"""Cameras and rigs: OpenCV conventions, vectorised numpy.

Conventions (shared/DESIGN.md): x_cam = R @ x_world + t, camera frame x right, y down,
z forward; pixel (0, 0) is the centre of the top-left pixel. Lens models (radtan, rational,
fisheye, vicon_radial), their coefficient counts and names are core/lens.py's table
``LENSES``; the lens functions live there too and are re-exported here for Camera's users.
:func:`project_points` is the reference projection: Camera.project is it, and the bundle's
and the fit's fast paths are tested against it (tests/test_projection_paths.py).

Arrays are named by what they hold and their shape: ``X_n3`` world points,
``xy_n2`` pixels, ``K_33`` intrinsics.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterable, Iterator, Sequence

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.lens import (  # noqa: F401  (re-exported: Camera's users import them from here)
    LENSES,
    PIXEL_LENS_MODELS,
    distort_normalized,
    lens_to_pixels,
    normalized_to_pixels,
    pixels_to_lens,
    pixels_to_normalized,
    undistort_normalized,
    vicon_distort_pixels,
    vicon_undistort_pixels,
)


def rodrigues(rvec_3: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) -> rotation matrix (3, 3)."""
    r = np.asarray(rvec_3, float).reshape(3)
    theta = np.linalg.norm(r)
    if theta < 1e-12:
        k = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
        return np.eye(3) + k
    k = r / theta
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * Kx + (1 - np.cos(theta)) * Kx @ Kx


def rotvec(R_33: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> rotation vector (3,), stable near 0 and pi."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R_33, float)).as_rotvec()


def nearest_rotation(M_33: np.ndarray) -> np.ndarray:
    """Project a near-rotation matrix onto SO(3) (SVD)."""
    U, _, Vt = np.linalg.svd(np.asarray(M_33, float))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return R


def project_points(R_33: np.ndarray, t_3: np.ndarray, K_33: np.ndarray, dist: np.ndarray, model: str,
                   X_n3: np.ndarray) -> np.ndarray:
    """World points (..., 3) -> recorded pixels (..., 2) of the camera x_cam = R X + t with
    intrinsics K and lens ``model`` / ``dist``: the reference projection. NaN for points at
    or behind the camera plane (z <= 1e-9)."""
    Xc = np.asarray(X_n3, float) @ np.asarray(R_33, float).T + np.asarray(t_3, float)
    z = Xc[..., 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = Xc[..., :2] / z
    xy = np.where(z > 1e-9, xy, np.nan)
    return lens_to_pixels(xy, K_33, dist, model)


@dataclass
class Camera:
    """One calibrated camera.

    size: (width, height) in pixels. K: 3x3 intrinsics. dist: lens coefficients of
    ``model``. R, t: world-to-camera rotation (3, 3) and translation (3,) in metres.
    meta: free-form per-camera extras carried through formats (e.g. caliscope
    rotation_count).
    """

    name: str
    size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    model: str = "radtan"
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.name = str(self.name)
        self.size = (int(self.size[0]), int(self.size[1]))
        self.K = np.asarray(self.K, float).reshape(3, 3)
        self.dist = np.asarray(self.dist, float).reshape(-1)
        self.R = np.asarray(self.R, float).reshape(3, 3)
        self.t = np.asarray(self.t, float).reshape(3)
        if self.model == "pinhole":
            self.model = "radtan"
        if self.model not in LENSES:
            raise UserError(
                f"camera {self.name}: unknown lens model '{self.model}'",
                f"use one of {', '.join(LENSES)}",
            )
        if len(self.dist) not in LENSES[self.model].n_coeffs:
            raise UserError(
                f"camera {self.name}: lens model {self.model} takes "
                f"{' or '.join(map(str, LENSES[self.model].n_coeffs))} coefficients, got {len(self.dist)}",
                "check the distortion coefficients",
            )

    # ---- derived quantities -------------------------------------------------------
    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates (3,)."""
        return -self.R.T @ self.t

    @property
    def rvec(self) -> np.ndarray:
        return rotvec(self.R)

    @property
    def P(self) -> np.ndarray:
        """3x4 projection matrix K [R | t] (ignores distortion)."""
        return self.K @ np.c_[self.R, self.t]

    @property
    def T_world_cam(self) -> np.ndarray:
        """4x4 camera-to-world pose."""
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = self.center
        return T

    def copy(self, **changes) -> "Camera":
        c = replace(self, **changes)
        c.K, c.dist, c.R, c.t = c.K.copy(), c.dist.copy(), c.R.copy(), c.t.copy()
        c.meta = dict(c.meta)
        return c

    # ---- projection -------------------------------------------------------------
    def to_camera(self, X_n3: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> camera-frame points (..., 3)."""
        X = np.asarray(X_n3, float)
        return X @ self.R.T + self.t

    def project(self, X_n3: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> distorted pixels (..., 2) (:func:`project_points`).

        Points behind the camera (z <= 0) give NaN.
        """
        return project_points(self.R, self.t, self.K, self.dist, self.model, X_n3)

    def lens_to_pixels(self, xy_n2: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (x/z, y/z) -> recorded (distorted) pixels."""
        return lens_to_pixels(xy_n2, self.K, self.dist, self.model)

    def pixels_to_lens(self, xy_n2: np.ndarray) -> np.ndarray:
        """Recorded pixels -> undistorted normalised coordinates (inverse of lens_to_pixels)."""
        return pixels_to_lens(xy_n2, self.K, self.dist, self.model)

    def normalized_to_pixels(self, xy_n2: np.ndarray) -> np.ndarray:
        return normalized_to_pixels(xy_n2, self.K)

    def pixels_to_normalized(self, xy_n2: np.ndarray) -> np.ndarray:
        """Distorted pixels -> distorted normalised coordinates (inverse of K only)."""
        return pixels_to_normalized(xy_n2, self.K)

    def undistort_pixels(self, xy_n2: np.ndarray) -> np.ndarray:
        """Distorted pixels -> pixels of the ideal pinhole camera with the same K."""
        return self.normalized_to_pixels(self.pixels_to_lens(xy_n2))

    def unproject(self, xy_n2: np.ndarray, depth: np.ndarray | float | None = None) -> np.ndarray:
        """Pixels (..., 2) -> camera-frame rays with z = 1 (..., 3), or points at ``depth``.

        With ``depth`` the result is in world coordinates (z-depth along the optical axis).
        """
        xn = self.pixels_to_lens(xy_n2)
        rays_c = np.concatenate([xn, np.ones_like(xn[..., :1])], -1)
        if depth is None:
            return rays_c
        Xc = rays_c * np.asarray(depth, float)[..., None]
        return (Xc - self.t) @ self.R

    def ray(self, xy_n2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels -> (origin (3,), unit world directions (..., 3))."""
        d = self.unproject(xy_n2) @ self.R  # R^T applied to row vectors
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return self.center, d

    def fundamental_to(self, other: "Camera") -> np.ndarray:
        """F with x_other^T F x_self = 0 for undistorted pixels (homogeneous)."""
        R_rel = other.R @ self.R.T
        t_rel = other.t - R_rel @ self.t
        tx = np.array([[0, -t_rel[2], t_rel[1]], [t_rel[2], 0, -t_rel[0]], [-t_rel[1], t_rel[0], 0]])
        E = tx @ R_rel
        F = np.linalg.inv(other.K).T @ E @ np.linalg.inv(self.K)
        n = np.linalg.norm(F)
        return F / n if n > 0 else F

    def scaled(self, sx: float, sy: float | None = None) -> "Camera":
        """The same camera for an image resized by (sx, sy) (pixel-centre convention)."""
        sy = sx if sy is None else sy
        S = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1]])
        dist = self.dist
        if self.model == "vicon_radial":
            if abs(sx - sy) > 1e-12 * max(sx, sy):
                raise UserError(f"camera {self.name}: the vicon_radial lens model cannot be resized by "
                                f"{sx:g} x {sy:g} (its distortion is radial in pixels)",
                                "resize both image axes by the same factor")
            # pp moves with the pixel grid; d^2 grows by sx^2
            dist = np.r_[S[:2, :2] @ self.dist[:2] + S[:2, 2], self.dist[2:] / sx ** np.array([2, 4, 6])]
        return self.copy(K=S @ self.K, dist=dist, size=(round(self.size[0] * sx), round(self.size[1] * sy)))


class Rig:
    """An ordered set of cameras, addressable by index or name."""

    def __init__(self, cameras: Iterable[Camera]):
        self.cameras: list[Camera] = list(cameras)
        names = [c.name for c in self.cameras]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise UserError(f"camera names repeat in the rig: {', '.join(dupes)}", "give every camera its own name")

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self.cameras)

    def __getitem__(self, key: int | str) -> Camera:
        if isinstance(key, str):
            for c in self.cameras:
                if c.name == key:
                    return c
            raise UserError(f"camera '{key}' is not in the calibration ({', '.join(self.names)})",
                            "calibrate that camera or check its name")
        return self.cameras[key]

    def __contains__(self, name: str) -> bool:
        return any(c.name == name for c in self.cameras)

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def subset(self, names: Sequence[str]) -> "Rig":
        return Rig([self[n] for n in names])

    def centers(self) -> np.ndarray:
        """Camera centres (C, 3)."""
        return np.stack([c.center for c in self.cameras]) if self.cameras else np.zeros((0, 3))

    def project(self, X_n3: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> pixels in every camera (C, ..., 2)."""
        return np.stack([c.project(X_n3) for c in self.cameras])

    def transformed(self, R_w: np.ndarray, t_w: np.ndarray, scale: float = 1.0) -> "Rig":
        """Rig in a new world frame where X_new = scale * R_w @ X_old + t_w."""
        out = []
        for c in self.cameras:
            R = c.R @ R_w.T
            t = scale * c.t - R @ t_w
            out.append(c.copy(R=R, t=t))
        return Rig(out)


def triangulate_points(rig: Rig, xy_cn2: np.ndarray, weight_cn: np.ndarray) -> np.ndarray:
    """Weighted linear (DLT) triangulation of N points seen by the rig's C cameras.

    xy_cn2 (C, N, 2) distorted pixels (NaN where unseen), weight_cn (C, N) >= 0 (0 = unseen).
    Returns X_n3 (N, 3) world points, NaN where fewer than two cameras see the point. Rows are
    built on undistorted normalised coordinates, so each view's equations are in the same units.
    """
    xy = np.asarray(xy_cn2, float)
    w = np.where(np.isfinite(xy).all(-1), np.asarray(weight_cn, float), 0.0)
    C, N = w.shape
    A = np.zeros((N, 2 * C, 4))
    for c, cam in enumerate(rig):
        xn = cam.unproject(np.nan_to_num(xy[c]))[:, :2]  # (N, 2)
        P = np.hstack([cam.R, cam.t[:, None]])  # normalised camera matrix
        A[:, 2 * c] = w[c, :, None] * (xn[:, :1] * P[2] - P[0])
        A[:, 2 * c + 1] = w[c, :, None] * (xn[:, 1:] * P[2] - P[1])
    _, _, Vt = np.linalg.svd(A)
    Xh = Vt[:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        X = Xh[:, :3] / Xh[:, 3:]
    return np.where(((w > 0).sum(0) >= 2)[:, None], X, np.nan)
