"""Cameras and rigs: OpenCV conventions, vectorised numpy.

Conventions (shared/DESIGN.md): x_cam = R @ x_world + t, camera frame x right, y down,
z forward; pixel (0, 0) is the centre of the top-left pixel. Lens models follow OpenCV:

- ``radtan``   : k1, k2, p1, p2[, k3]                  (cv2.projectPoints, 4 or 5 coeffs)
- ``rational`` : k1, k2, p1, p2, k3, k4, k5, k6[, s1..s4] (8 or 12 coeffs)
- ``fisheye``  : k1, k2, k3, k4                         (cv2.fisheye, equidistant)
- ``vicon_radial`` : pp_x, pp_y, rad_1, rad_2, rad_3 (pixels; Vicon's VICON_RADIAL2, the
  MAMMA release's ``vicon_radial_2``): a pinhole-projected pixel u (through K) is recorded
  at pp + (u - pp)(1 + rad_1 d^2 + rad_2 d^4 + rad_3 d^6), d^2 = |u - pp|^2 in pixels. It
  acts on pixels, not on normalised coordinates, so only Camera's methods (project,
  unproject, undistort_pixels) apply it; :func:`distort_normalized` refuses it.

Arrays are named by what they hold and their shape: ``X_n3`` world points,
``xy_n2`` pixels, ``K_33`` intrinsics.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterable, Iterator, Sequence

import numpy as np

from mamma_kit.core.errors import UserError

LENS_MODELS = {"radtan": (0, 4, 5), "rational": (8, 12), "fisheye": (4,), "vicon_radial": (5,)}
PIXEL_LENS_MODELS = ("vicon_radial",)  # lens models defined on pixels (need K), not normalised coordinates


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


def distort_normalized(xy_n2: np.ndarray, model: str, dist: np.ndarray) -> np.ndarray:
    """Apply a lens model to normalised image coordinates (x/z, y/z)."""
    if model in PIXEL_LENS_MODELS:
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


def undistort_normalized(xyd_n2: np.ndarray, model: str, dist: np.ndarray, iters: int = 30) -> np.ndarray:
    """Invert :func:`distort_normalized` by Gauss-Newton with a numeric 2x2 Jacobian.

    Vectorised over points; converges to ~1e-14 for the distortion of real lenses.
    """
    xyd = np.asarray(xyd_n2, float)
    if not np.any(dist):
        return xyd.copy()
    xy = xyd.copy()
    eps = 1e-7
    for it in range(iters):
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
        if self.model not in LENS_MODELS:
            raise UserError(
                f"camera {self.name}: unknown lens model '{self.model}'",
                f"use one of {', '.join(LENS_MODELS)}",
            )
        if len(self.dist) not in LENS_MODELS[self.model]:
            raise UserError(
                f"camera {self.name}: lens model {self.model} takes "
                f"{' or '.join(map(str, LENS_MODELS[self.model]))} coefficients, got {len(self.dist)}",
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
        """World points (..., 3) -> distorted pixels (..., 2).

        Points behind the camera (z <= 0) give NaN.
        """
        Xc = self.to_camera(X_n3)
        z = Xc[..., 2:3]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = Xc[..., :2] / z
        xy = np.where(z > 1e-9, xy, np.nan)
        return self.lens_to_pixels(xy)

    def lens_to_pixels(self, xy_n2: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (x/z, y/z) -> recorded (distorted) pixels."""
        if self.model == "vicon_radial":
            return vicon_distort_pixels(self.normalized_to_pixels(xy_n2), self.dist)
        return self.normalized_to_pixels(distort_normalized(xy_n2, self.model, self.dist))

    def pixels_to_lens(self, xy_n2: np.ndarray) -> np.ndarray:
        """Recorded pixels -> undistorted normalised coordinates (inverse of lens_to_pixels)."""
        if self.model == "vicon_radial":
            return self.pixels_to_normalized(vicon_undistort_pixels(xy_n2, self.dist))
        return undistort_normalized(self.pixels_to_normalized(xy_n2), self.model, self.dist)

    def normalized_to_pixels(self, xy_n2: np.ndarray) -> np.ndarray:
        K = self.K
        x, y = xy_n2[..., 0], xy_n2[..., 1]
        u = K[0, 0] * x + K[0, 1] * y + K[0, 2]
        v = K[1, 1] * y + K[1, 2]
        return np.stack([u, v], -1)

    def pixels_to_normalized(self, xy_n2: np.ndarray) -> np.ndarray:
        """Distorted pixels -> distorted normalised coordinates (inverse of K only)."""
        K = self.K
        xy = np.asarray(xy_n2, float)
        y = (xy[..., 1] - K[1, 2]) / K[1, 1]
        x = (xy[..., 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return np.stack([x, y], -1)

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
