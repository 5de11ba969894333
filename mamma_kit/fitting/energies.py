"""Differentiable energies of the L-BFGS stages (3 and 4), over all frames of a chunk at once.

Units: every term is a sum of squared, whitened residuals (twice a negative log-likelihood),
so the weights are standard deviations with physical units:

- reprojection: sum p_cl rho(|(mu - Pi(V)) / sigma'|^2), Geman-McClure rho (see gauss_newton);
- pose prior: |theta_j|^2 / s_j^2 on local rotations (light; fingers, spine);
- temporal: |joint acceleration|^2 / s_acc^2 (m/s^2), second divided differences on the
  true (VFR) frame times;
- contact and floor terms come from contact.py (stage 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from mamma_kit.body import skeleton as sk
from mamma_kit.body.lbs import pose_restricted
from mamma_kit.fitting.gauss_newton import robust
from mamma_kit.fitting.projection import RigTensors

F32 = torch.float32


def pose_dict(pose: torch.Tensor, transl: torch.Tensor, betas: torch.Tensor) -> dict[str, torch.Tensor]:
    """(P, T, 55, 3) axis-angle + transl (P, T, 3) + betas (P, B) -> body.lbs parameter dict."""
    out = {"transl": transl, "betas": betas[:, None]}
    off = 0
    for k, n in sk.POSE_PARAMS.items():
        out[k] = pose[:, :, off // 3:(off + n) // 3].reshape(*pose.shape[:2], n)
        off += n
    return out


def acceleration(x: torch.Tensor, times: torch.Tensor) -> torch.Tensor:
    """Second divided differences along dim 1 of x (P, T, ...) at times (T,) -> (P, T-2, ...)."""
    dt = times[1:] - times[:-1]
    shape = (1, -1) + (1,) * (x.ndim - 2)
    v = (x[:, 1:] - x[:, :-1]) / dt.reshape(shape)
    return 2 * (v[:, 1:] - v[:, :-1]) / (times[2:] - times[:-2]).reshape(shape)


@dataclass
class TemporalConfig:
    accel_sigma: float = 30.0  # m/s^2 per joint coordinate
    weight_frames: torch.Tensor | None = None  # (T,) 1 where a frame counts


class ReprojectionEnergy:
    """sum p rho(|r / sigma|^2) for posed landmarks v (P, T, L, 3)."""

    def __init__(self, cams: RigTensors, xy: torch.Tensor, sigma: torch.Tensor, w: torch.Tensor, gamma: float):
        self.cams = cams.to(F32)
        self.xy, self.inv_sigma, self.w = xy.to(F32), (1.0 / sigma).to(F32), w.to(F32)
        self.gamma = gamma

    def residuals(self, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        uv, valid = self.cams.project(v[None])
        return uv, valid

    def __call__(self, v: torch.Tensor) -> torch.Tensor:
        uv, valid = self.cams.project(v[None])
        r = (self.xy - uv) * self.inv_sigma
        rho, _ = robust((r * r).sum(-1), self.gamma)
        return (rho * self.w * valid).sum(dtype=torch.float64)

    @torch.no_grad()
    def pixel_errors(self, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Reprojection error (C, P, T, L) px and validity."""
        uv, valid = self.cams.project(v[None].to(F32))
        return (self.xy - uv).norm(dim=-1), valid


class PoseEnergy:
    """Everything but contact for stage 3 (and the base of stage 4)."""

    def __init__(self, model, reproj: ReprojectionEnergy, times: np.ndarray, active: np.ndarray,
                 prior_sigma: np.ndarray, temporal: TemporalConfig | None):
        self.model = model
        self.reproj = reproj
        self.times = torch.as_tensor(times - times[0], dtype=torch.float64)
        self.active = torch.as_tensor(active)
        ps = np.asarray(prior_sigma, float)[active]
        self.prior_w = torch.as_tensor(np.where(np.isfinite(ps), 1.0 / ps ** 2, 0.0), dtype=F32)
        self.temporal = temporal

    def terms(self, pose_act: torch.Tensor, pose_fixed: torch.Tensor, transl: torch.Tensor,
              betas: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor]:
        pose = pose_fixed.clone()
        pose[:, :, self.active] = pose_act
        v, joints = pose_restricted(self.model, pose_dict(pose, transl, betas))
        out = {"reprojection": self.reproj(v)}
        out["pose_prior"] = ((pose_act * pose_act).sum(-1) * self.prior_w).sum(dtype=torch.float64)
        if self.temporal is not None and joints.shape[1] >= 3:
            a = acceleration(joints.to(torch.float64), self.times)  # (P, T-2, 55, 3)
            e = (a * a).sum((-1, -2)) / self.temporal.accel_sigma ** 2
            if self.temporal.weight_frames is not None:
                e = e * self.temporal.weight_frames[1:-1]
            out["temporal"] = e.sum()
        return out, v, joints
