"""MammaNet training losses (paper, Dense Landmark Estimation; OFFICIAL-MAMMANET.md training facts).

- position: Gaussian NLL with an isotropic sigma in normalised crop units,
  min(|mu - mu'|^2 / (2 sigma^2), 25) + 2 log sigma (2 = one log sigma per axis), weight 100;
- visibility: binary cross-entropy, weight 1;
- person contact and floor contact: sigmoid focal loss (alpha 0.9, gamma 2), weight 1 each;
- models with a dense head (config ``dense_head``): L1 of its soft-argmax positions, weight 10,
  and cross-entropy of its token distribution against a Gaussian around the truth, weight 1;
- keypoint-guided models (head ``sampled``): L1 of the keypoint prior's positions plus 0.1 x the
  cross-entropy of its visibility and the focal loss of its floor contact, weight 10, so the prior
  learns a good start on its own and the refinement learns what the image adds;
- every term weighted per landmark (``landmark_weights``): 1 inside the crop, exp(-2 |r - 1|) outside
  with r = max(|n_x|, |n_y|) the landmark's normalised Chebyshev radius (the crop border is r = 1);
  hand and foot landmarks doubled when their part is at least partly inside the crop.

Weighted terms are averaged as sum(w * loss) / sum(w) over the batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

#: landmark part names whose weights double when partly inside the crop
DOUBLED_PARTS = ("left_hand", "right_hand", "left_foot", "right_foot")


@dataclass(frozen=True)
class LossWeights:
    xy: float = 100.0
    visibility: float = 1.0
    contact: float = 1.0
    floor_contact: float = 1.0
    dense: float = 10.0  # L1 (normalised units) of the dense head's soft-argmax, when the model has one
    dense_ce: float = 1.0  # cross-entropy of its token distribution against a Gaussian around the truth
    prior: float = 10.0  # L1 (normalised units) of the keypoint prior's positions, when the model has one
    nll_clip: float = 25.0
    focal_alpha: float = 0.9
    focal_gamma: float = 2.0


def landmark_weights(xy_n_bl2: torch.Tensor, part_l: torch.Tensor | None = None,
                     doubled_part_ids: list[int] | tuple[int, ...] = ()) -> torch.Tensor:
    """(B, L) per-landmark weights from ground-truth normalised positions."""
    r = xy_n_bl2.abs().amax(-1)
    inside = r <= 1.0
    w = torch.where(inside, torch.ones_like(r), torch.exp(-2.0 * (r - 1.0).abs()))
    if part_l is not None and len(doubled_part_ids):
        part_l = part_l.to(xy_n_bl2.device)
        for pid in doubled_part_ids:  # a handful of parts, not landmarks
            sel = part_l == pid  # (L,)
            if not bool(sel.any()):
                continue
            partly_inside = (inside & sel[None]).any(1, keepdim=True)  # (B, 1)
            w = torch.where(sel[None] & partly_inside, 2.0 * w, w)
    return w


def gaussian_nll(xy_pred: torch.Tensor, log_sigma: torch.Tensor, xy_gt: torch.Tensor, clip: float = 25.0) -> torch.Tensor:
    """(B, L) 2-D isotropic Gaussian NLL (without the constant), the Mahalanobis term clipped."""
    d2 = (xy_pred - xy_gt).pow(2).sum(-1)
    return torch.clamp(d2 / (2.0 * torch.exp(2.0 * log_sigma)), max=clip) + 2.0 * log_sigma


def bce(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return F.binary_cross_entropy_with_logits(logits, target.float(), reduction="none")


def sigmoid_focal(logits: torch.Tensor, target: torch.Tensor, alpha: float = 0.9, gamma: float = 2.0) -> torch.Tensor:
    """(B, L) focal loss (Lin et al. 2017): alpha_t (1 - p_t)^gamma CE."""
    t = target.float()
    p = torch.sigmoid(logits)
    ce = F.binary_cross_entropy_with_logits(logits, t, reduction="none")
    p_t = p * t + (1 - p) * (1 - t)
    alpha_t = alpha * t + (1 - alpha) * (1 - t)
    return alpha_t * (1 - p_t).pow(gamma) * ce


def dense_cross_entropy(logits_bnl: torch.Tensor, centres_n2: torch.Tensor, xy_bl2: torch.Tensor) -> torch.Tensor:
    """(B, L) cross-entropy of the softmax over tokens against a Gaussian around each true
    position (0.6 of a token's size per axis): a strong, dense signal from the first step,
    where the soft-argmax alone barely moves a flat distribution."""
    xs, ys = torch.unique(centres_n2[:, 0]), torch.unique(centres_n2[:, 1])
    step = torch.stack([xs[1] - xs[0], ys[1] - ys[0]])  # token size (x, y), normalised
    z = (centres_n2[None, :, None, :] - xy_bl2[:, None]) / (0.6 * step)  # (B, N, L, 2)
    q = torch.softmax(-0.5 * (z * z).sum(-1), dim=1)
    return -(q * torch.log_softmax(logits_bnl, dim=1)).sum(1)


def _wmean(loss: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    return (loss * w).sum() / w.sum().clamp_min(1e-6)


def prior_loss(out: dict, batch: dict, w: torch.Tensor, weights: LossWeights = LossWeights()) -> torch.Tensor:
    """The keypoint prior's own term: L1 of its positions + 0.1 x (visibility cross-entropy + floor
    focal loss) of its logits (the refinement adds to those logits, detached)."""
    return _wmean((out["xy_prior"] - batch["xy_n"]).abs().sum(-1), w) + 0.1 * (
        _wmean(bce(out["vis_logit_prior"], batch["visibility"]), w)
        + _wmean(sigmoid_focal(out["floor_logit_prior"], batch["floor_contact"], weights.focal_alpha,
                               weights.focal_gamma), w))


def mammanet_loss(out: dict, batch: dict, weights: LossWeights = LossWeights(),
                  part_l: torch.Tensor | None = None, doubled_part_ids=()) -> tuple[torch.Tensor, dict[str, float]]:
    """Total loss and its terms. ``batch``: xy_n (B, L, 2), visibility, contact, floor_contact (B, L),
    optional ``weight`` (B, L) overriding the per-landmark weights."""
    w = batch.get("weight")
    if w is None:
        w = landmark_weights(batch["xy_n"], part_l, doubled_part_ids)
    nll = _wmean(gaussian_nll(out["xy"], out["log_sigma"], batch["xy_n"], weights.nll_clip), w)
    vis = _wmean(bce(out["vis_logit"], batch["visibility"]), w)
    con = _wmean(sigmoid_focal(out["contact_logit"], batch["contact"], weights.focal_alpha, weights.focal_gamma), w)
    flo = _wmean(sigmoid_focal(out["floor_logit"], batch["floor_contact"], weights.focal_alpha, weights.focal_gamma), w)
    total = weights.xy * nll + weights.visibility * vis + weights.contact * con + weights.floor_contact * flo
    terms = {"nll": float(nll.detach()), "vis": float(vis.detach()), "contact": float(con.detach()),
             "floor": float(flo.detach())}
    if "xy_dense" in out and weights.dense > 0:
        dense = _wmean((out["xy_dense"] - batch["xy_n"]).abs().sum(-1), w)
        total = total + weights.dense * dense
        terms["dense"] = float(dense.detach())
    if "xy_prior" in out and weights.prior > 0:
        prior = prior_loss(out, batch, w, weights)
        total = total + weights.prior * prior
        terms["prior"] = float(prior.detach())
    if "dense_logits" in out and weights.dense_ce > 0:
        ce = _wmean(dense_cross_entropy(out["dense_logits"], out["dense_centres"], batch["xy_n"]), w)
        total = total + weights.dense_ce * ce
        terms["dense_ce"] = float(ce.detach())
    return total, {"loss": float(total.detach()), **terms}
