"""Training batches: crops of shards -> collated numpy batches -> tensors -> the network.

Shared by training (train.py) and the layout-visibility fit (layout_vis.py), below both.
"""

from __future__ import annotations

import numpy as np
import torch

from mamma_kit.landmarks import crop as C
from mamma_kit.landmarks.augment import AugmentConfig, collate, prepare_sample
from mamma_kit.landmarks.config import MammaNetConfig
from mamma_kit.landmarks.data import CropShards


def batch_to_torch(b: dict[str, np.ndarray], device: str) -> dict[str, torch.Tensor]:
    """A collated batch of ``prepare_sample`` outputs -> tensors (the network's inputs and labels)."""
    t = {"image": C.normalise_images(b["image"], device), "mask": C.mask_tensor(b["mask"], device),
         **{k: torch.as_tensor(b[k], device=device) for k in ("xy_n", "visibility", "contact", "floor_contact")}}
    if "others" in b:
        t["others"] = C.mask_tensor(b["others"], device)
    if "keypoints" in b:
        t["keypoints"] = torch.as_tensor(b["keypoints"], device=device)
    return t


def run_model(model: torch.nn.Module, t: dict[str, torch.Tensor]):
    """``model`` (a MammaNet) on a batch of ``batch_to_torch``: only the inputs its config reads."""
    cfg = model.cfg
    return model(t["image"], t["mask"] if cfg.use_mask else None, t.get("keypoints") if cfg.keypoints_in else None,
                 t.get("others") if cfg.others_in_stem else None)


def make_batch(shards: CropShards, indices: np.ndarray, cfg: MammaNetConfig, aug: AugmentConfig | None,
               seed_key: tuple[int, ...]) -> dict[str, np.ndarray]:
    """The crops ``indices`` of ``shards`` at the network's input size, augmented by ``aug`` (None:
    not), each from its own generator seeded by (*seed_key, position): a pure function of the key."""
    H, W = cfg.input_hw
    return collate([prepare_sample(shards[int(i)], (W, H), cfg.antialias, aug, np.random.default_rng([*seed_key, j]))
                    for j, i in enumerate(indices)])
