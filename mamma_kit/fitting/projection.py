"""Camera projection in torch for the fit: the lens models of core/lens.py's table marked
``fit`` (OpenCV radtan / rational / fisheye), batched over cameras, with the 2x3 Jacobian
d pixel / d world point for Gauss-Newton.

``RigTensors.project(X_c_n3)`` takes points per camera (C, ..., 3) and returns pixels
(C, ..., 2) and a validity mask (points in front of the camera); it is what the fit's
energies evaluate (fitting/gauss_newton.py's Levenberg-Marquardt accepts or rejects a step
on it) and stays differentiable by autograd. ``project_jacobian`` returns the pixels and the
Jacobian without autograd, in closed form (the lens part too), for the normal equations.

This is a fast path beside core's reference projection (core.camera.project_points), not a
shared implementation: it runs in torch on every camera at once with per-camera coefficient
tensors, which core's numpy lens functions cannot do. tests/test_projection_paths.py checks
that its pixels agree with Camera.project within 1e-9 px for every lens model it implements,
and its Jacobian with autograd and with finite differences of Camera.project.
``vicon_radial`` is not implemented here: it acts on pixels about its own centre, not on the
normalised coordinates this path distorts, and a Vicon calibration converts to the closest
radtan lens with a report of what moves (from_rig's error says how).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from mamma_kit.core.camera import Rig
from mamma_kit.core.lens import FIT_MODELS, LENSES

MIN_DEPTH = 1e-3  # m: points closer to (or behind) the camera plane do not project
N_SLOTS = max(max(LENSES[m].n_coeffs) for m in FIT_MODELS)  # 12: rational's k1..k6, p1, p2, s1..s4


@dataclass
class RigTensors:
    """C cameras as tensors: R (C, 3, 3), t (C, 3), K (C, 3, 3), dist (C, 12) zero-padded
    (each camera's coefficients in the table's order), fisheye (C,) bool, size (C, 2) [w, h];
    names in rig order."""

    names: list[str]
    R: torch.Tensor
    t: torch.Tensor
    K: torch.Tensor
    dist: torch.Tensor
    fisheye: torch.Tensor
    size: torch.Tensor

    @classmethod
    def from_rig(cls, rig: Rig, dtype=torch.float64) -> "RigTensors":
        other = sorted({c.model for c in rig} - set(FIT_MODELS))
        if other:
            from mamma_kit.core.errors import UserError

            raise UserError(f"the fit projects OpenCV lenses ({', '.join(FIT_MODELS)}), not {', '.join(other)}",
                            "convert the calibration with `mamma-kit calib convert IN OUT --to opencv-json` (it fits "
                            "the closest radtan lens and says how far projections move), then fit again")
        C = len(rig)
        dist = np.zeros((C, N_SLOTS))
        for i, c in enumerate(rig):
            dist[i, :len(c.dist)] = c.dist
        t = lambda a: torch.as_tensor(np.asarray(a, float), dtype=dtype)  # noqa: E731
        return cls([c.name for c in rig], t([c.R for c in rig]), t([c.t for c in rig]), t([c.K for c in rig]),
                   t(dist), torch.as_tensor([c.model == "fisheye" for c in rig]), t([c.size for c in rig]))

    def __len__(self) -> int:
        return len(self.names)

    def to(self, dtype) -> "RigTensors":
        return RigTensors(self.names, self.R.to(dtype), self.t.to(dtype), self.K.to(dtype), self.dist.to(dtype),
                          self.fisheye, self.size.to(dtype))

    def subset(self, idx) -> "RigTensors":
        idx = list(idx)
        return RigTensors([self.names[i] for i in idx], self.R[idx], self.t[idx], self.K[idx], self.dist[idx],
                          self.fisheye[idx], self.size[idx])

    def _bc(self, a: torch.Tensor, nd: int) -> torch.Tensor:
        """Per-camera tensor (C, *s) -> (C, 1, ..., 1, *s) to broadcast over nd point dims."""
        return a.reshape(a.shape[0], *([1] * nd), *a.shape[1:])

    def to_camera(self, X: torch.Tensor) -> torch.Tensor:
        """World points (C, ..., 3) (or broadcastable) -> camera frame (C, ..., 3)."""
        nd = X.ndim - 2
        R, t = self._bc(self.R.to(X.dtype), nd), self._bc(self.t.to(X.dtype), nd)
        return (R @ X.unsqueeze(-1)).squeeze(-1) + t

    def _lens_terms(self, xn: torch.Tensor):
        """nd (point dims), x, y, r2 (C, ...) of normalised points (C, ..., 2) and the 12
        coefficient slots, each (C, 1, ..., 1) to broadcast over the points."""
        nd = xn.ndim - 2
        x, y = xn[..., 0], xn[..., 1]
        return nd, x, y, x * x + y * y, self._bc(self.dist.to(xn.dtype), nd).unbind(-1)

    def distort(self, xn: torch.Tensor) -> torch.Tensor:
        """Normalised (C, ..., 2) -> distorted normalised (C, ..., 2)."""
        nd, x, y, r2, (k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4) = self._lens_terms(xn)
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r2 * r2
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r2 * r2
        out = torch.stack([xd, yd], -1)
        if bool(self.fisheye.any()):
            r = torch.sqrt(r2 + 1e-30)
            th = torch.atan(r)
            t2 = th * th
            thd = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (p1 + t2 * p2))))  # fisheye k1..k4 in slots 0..3
            scale = torch.where(r > 1e-12, thd / r, torch.ones_like(r))
            fe = xn * scale.unsqueeze(-1)
            fmask = self._bc(self.fisheye, nd + 1)
            out = torch.where(fmask, fe, out)
        return out

    def to_pixels(self, xd: torch.Tensor) -> torch.Tensor:
        nd = xd.ndim - 2
        K = self._bc(self.K.to(xd.dtype), nd)
        u = K[..., 0, 0] * xd[..., 0] + K[..., 0, 1] * xd[..., 1] + K[..., 0, 2]
        v = K[..., 1, 1] * xd[..., 1] + K[..., 1, 2]
        return torch.stack([u, v], -1)

    def project(self, X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points (C, ..., 3) -> pixels (C, ..., 2), valid (C, ...) (in front of the
        camera). Invalid points project as if they were at MIN_DEPTH (finite, differentiable)."""
        Xc = self.to_camera(X)
        z = Xc[..., 2]
        valid = z > MIN_DEPTH
        zs = torch.where(valid, z, torch.full_like(z, MIN_DEPTH))
        xn = Xc[..., :2] / zs.unsqueeze(-1)
        return self.to_pixels(self.distort(xn)), valid

    def distort_jacobian(self, xn: torch.Tensor) -> torch.Tensor:
        """d distorted / d normalised (C, ..., 2, 2), closed form for every lens model."""
        nd, x, y, r2, (k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4) = self._lens_terms(xn)
        a = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        b = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        da = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        db = k4 + r2 * (2 * k5 + 3 * k6 * r2)
        rad = a / b
        drad = (da * b - a * db) / (b * b)  # d rad / d r2
        sx = s1 + 2 * s2 * r2
        sy = s3 + 2 * s4 * r2
        j00 = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x + 2 * x * sx
        j01 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * y * sx
        j10 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * x * sy
        j11 = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x + 2 * y * sy
        J = torch.stack([torch.stack([j00, j01], -1), torch.stack([j10, j11], -1)], -2)
        if bool(self.fisheye.any()):
            r = torch.sqrt(r2).clamp(min=1e-9)
            th = torch.atan(r)
            t2 = th * th
            thd = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (p1 + t2 * p2))))
            dthd = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * p1 + t2 * 9 * p2)))
            s = thd / r
            ds_r = (dthd / (1 + r2) * r - thd) / (r2 * r)  # (d s / d r) / r
            eye = torch.eye(2, dtype=xn.dtype)
            Jf = s[..., None, None] * eye + ds_r[..., None, None] * (xn.unsqueeze(-1) * xn.unsqueeze(-2))
            J = torch.where(self._bc(self.fisheye, nd + 2), Jf, J)
        return J

    @torch.no_grad()
    def project_jacobian(self, X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Pixels (C, ..., 2), d pixel / d X (C, ..., 2, 3) and valid (C, ...), in X's dtype."""
        nd = X.ndim - 2
        dt = X.dtype
        Xc = self.to_camera(X)
        z = Xc[..., 2]
        valid = z > MIN_DEPTH
        inv = 1.0 / torch.where(valid, z, torch.full_like(z, MIN_DEPTH))
        xn = Xc[..., :2] * inv.unsqueeze(-1)
        KJ = self._bc(self.K.to(dt)[:, :2, :2], nd) @ self.distort_jacobian(xn)  # (C, ..., 2, 2)
        # d xn / d Xc = [[1/z, 0, -x/z], [0, 1/z, -y/z]] / z ... folded: (KJ @ Jn) @ R
        M = torch.cat([KJ * inv[..., None, None], -(KJ @ xn.unsqueeze(-1)) * inv[..., None, None]], -1)  # (.., 2, 3)
        J = M @ self._bc(self.R.to(dt), nd)
        return self.to_pixels(self.distort(xn)), J, valid

    def centers(self) -> torch.Tensor:
        """(C, 3) camera centres."""
        return -(self.R.transpose(-1, -2) @ self.t.unsqueeze(-1)).squeeze(-1)
