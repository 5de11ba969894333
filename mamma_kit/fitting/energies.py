"""The reprojection term in torch (autograd-friendly) for reports and the stage-3 sigma
rescaling, and the SMPL-X parameter dict of the fit's pose arrays.

The optimisation itself runs in gauss_newton.py (same energy: sum p rho(|(mu - Pi(V)) /
sigma|^2), Geman-McClure rho).
"""

from __future__ import annotations

import torch

from mamma_kit.body import skeleton as sk
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


class ReprojectionEnergy:
    """sum p rho(|r / sigma|^2) for posed landmarks v (P, T, L, 3)."""

    def __init__(self, cams: RigTensors, xy: torch.Tensor, sigma: torch.Tensor, w: torch.Tensor, gamma: float):
        self.cams = cams.to(F32)
        self.xy, self.inv_sigma, self.w = xy.to(F32), (1.0 / sigma).to(F32), w.to(F32)
        self.gamma = gamma

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
