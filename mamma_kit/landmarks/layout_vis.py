"""Visibility from the layout of a person's landmarks: a small MLP head over all 2D positions.

Whether a landmark is visible is mostly self-occlusion, which the 2D layout of all 512
landmarks reveals (which way the body faces, which limb crosses which): an MLP over the
layout alone reaches 87 % on held-out crops of another recipe from true positions, in a
minute on a CPU. The image decoder's own visibility output needs far longer training than
the embedded CPU schedule gives it (it stayed at the constant guess), so the embedded weights
replace it by this head, fitted after the network on the network's own predicted positions
(and noisy true ones) of the training crops. Not in the paper's or the official architecture.

Positions enter as (B, L, 2) in crop pixels (any common scale: the layout is centred and
divided by its spread, so only its shape counts).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from mamma_kit.core import log


def normalise_layout(xy_bl2: torch.Tensor) -> torch.Tensor:
    """(B, L, 2) -> (B, 2L): centred on the mean landmark, divided by the mean spread."""
    c = xy_bl2.mean(1, keepdim=True)
    s = (xy_bl2 - c).std(1, keepdim=True).mean(2, keepdim=True).clamp_min(1e-6)
    return ((xy_bl2 - c) / s).flatten(1)


class LayoutVisibility(nn.Module):
    """(B, L, 2) landmark positions -> (B, L) visibility logits."""

    def __init__(self, n_landmarks: int, hidden: int = 512):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(2 * n_landmarks, hidden), nn.GELU(), nn.Linear(hidden, hidden), nn.GELU(),
                                 nn.Linear(hidden, n_landmarks))

    def forward(self, xy_bl2: torch.Tensor) -> torch.Tensor:
        return self.mlp(normalise_layout(xy_bl2))


def _gt_layouts(dirs: list[Path]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True positions (N, L, 2) crop px, visibility (N, L) and box heights (N,) of shard folders."""
    xy, vis, box_h = [], [], []
    for d in dirs:
        for f in sorted(Path(d).glob("shard_*.npz")):
            with np.load(f) as z:
                xy.append(z["xy"].astype(np.float32))
                vis.append(z["visibility"].astype(np.float32))
                box_h.append((z["box"][:, 3] - z["box"][:, 1]).astype(np.float32))  # x0 y0 x1 y1
    return np.concatenate(xy), np.concatenate(vis), np.concatenate(box_h)


def _predicted_layouts(model, shards, n: int, batch: int = 16, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """The network's positions (N, L, 2) in input-crop px and true visibility on ``n`` crops."""
    from mamma_kit.landmarks.batches import batch_to_torch, make_batch, run_model

    cfg = model.cfg
    H, W = cfg.input_hw
    half = torch.tensor([W / 2, H / 2])
    idx = np.sort(np.random.default_rng(seed).permutation(len(shards))[:n])
    xs, vs = [], []
    model.eval()
    with torch.no_grad():
        for a in range(0, len(idx), batch):
            b = make_batch(shards, idx[a:a + batch], cfg, None, (seed, a))
            out = run_model(model, batch_to_torch(b, "cpu"))
            xs.append((out["xy"].float() * half).numpy())
            vs.append(np.asarray(b["visibility"], np.float32))
    return np.concatenate(xs), np.concatenate(vs)


def fit_layout_visibility(model, train_dirs: list[Path], n_predicted: int = 2000, epochs: int = 20,
                          seed: int = 0) -> tuple[LayoutVisibility, dict]:
    """Fit a :class:`LayoutVisibility` for ``model`` (a trained MammaNet) on its training crops:
    its own predictions on ``n_predicted`` crops (the error structure it will see) and all true
    layouts with Gaussian noise of 0-8 % of the box height (robustness beyond that)."""
    from mamma_kit.landmarks.data import CropShards

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    xy_g, vis_g, box_h = _gt_layouts(train_dirs)
    log.info(f"layout visibility: the network on {n_predicted} training crops")
    xy_p, vis_p = _predicted_layouts(model, CropShards(train_dirs), n_predicted)
    head = LayoutVisibility(model.cfg.n_landmarks)
    opt = torch.optim.AdamW(head.parameters(), 1e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    Xg, Vg, Hg = torch.from_numpy(xy_g), torch.from_numpy(vis_g), torch.from_numpy(box_h)
    Xp, Vp = torch.from_numpy(xy_p), torch.from_numpy(vis_p)
    B = 256
    for ep in range(epochs):
        head.train()
        # every epoch: all noisy true layouts and the predicted ones 4 times (they are fewer)
        noise = Hg[:, None, None] * torch.from_numpy(rng.uniform(0, 0.08, (len(Xg), 1, 1)).astype(np.float32))
        X = torch.cat([Xg + noise * torch.randn_like(Xg)] + [Xp] * 4)
        V = torch.cat([Vg] + [Vp] * 4)
        perm = torch.randperm(len(X))
        for i in range(0, len(X), B):
            j = perm[i:i + B]
            loss = nn.functional.binary_cross_entropy_with_logits(head(X[j]), V[j])
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
    head.eval()
    with torch.no_grad():
        acc_p = float(((head(Xp) > 0).float() == Vp).float().mean())
    info = {"train_crops": int(len(Xg)), "predicted_crops": int(len(Xp)), "epochs": epochs,
            "train_accuracy_on_predictions": round(acc_p, 4), "seconds": round(time.perf_counter() - t0, 1)}
    log.info(f"layout visibility fitted in {info['seconds']:.0f} s (training accuracy on predictions {acc_p:.3f})")
    return head, info
