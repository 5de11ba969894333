"""The fit's pose arrays as body.lbs parameters, and the pixel errors that stage 3's sigma
rescaling starts from.

The energies themselves are in gauss_newton.py (the robust reprojection term sum p rho(|(mu
- Pi(V)) / sigma|^2) with Geman-McClure rho, the priors, the temporal term) and contact.py.
"""

from __future__ import annotations

import torch

from mamma_kit.body import skeleton as sk
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


@torch.no_grad()
def pixel_errors(cams: RigTensors, xy: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Reprojection error (C, P, T, L) px of posed points v (P, T, L, 3) against observed
    xy (C, P, T, L, 2), and the projection's validity (C, P, T, L); float32."""
    uv, valid = cams.to(F32).project(v[None].to(F32))
    return (xy.to(F32) - uv).norm(dim=-1), valid
