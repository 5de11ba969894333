"""MammaNet: dense surface landmarks (xy, sigma, visibility, person contact, floor contact) per person crop.

Public API (imported lazily, so ``import mamma_kit.landmarks`` does not load torch):

- configs: ``get_config(name, **overrides)``, ``CONFIGS`` (official, embedded, embedded-256, embedded-single,
  embedded-nomask, official-single, tiny, tiny-single), ``MammaNetConfig``
- model: ``build_model(cfg_or_name)``, ``MammaNet``, ``state_dict_shapes(cfg_or_name)``
- weights: ``load_model(weights=None, arch=None, device="cpu")``, ``save_weights(path, model, landmark_set, card)``,
  ``random_model(arch)``
- inference: ``Predictor(loaded)`` with ``crop``, ``predict_crops``, ``to_image``, ``predict_image``;
  ``run_camera(predictor, cam, mask_tracks, video_path, batch)``
- hand refinement: ``mamma_kit.landmarks.hands`` (``hand_refiner(landmark_set, "auto")``, ``HandRefiner``,
  the hand crop contract); its training: ``mamma_kit.landmarks.hand_train``
- crop contract: ``mamma_kit.landmarks.crop`` (expand_box, warp_crop, normalised_to_image, sigma_to_pixels, ...)
- training: ``mamma_kit.landmarks.train.train(config_path, resume, device)``, ``CropShards(dirs)``,
  ``write_crop_shards``
- ground truth with noise: ``noisy_gt_landmarks(ws, cam, noise, outliers, seed)``
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "get_config": "config", "CONFIGS": "config", "MammaNetConfig": "config", "DEFAULT_ARCH": "config",
    "build_model": "model", "MammaNet": "model", "state_dict_shapes": "model",
    "load_model": "weights", "save_weights": "weights", "random_model": "weights", "LoadedModel": "weights",
    "Predictor": "inference", "run_camera": "inference",
    "load_train_config": "train",
    "CropShards": "data", "write_crop_shards": "data",
    "noisy_gt_landmarks": "gt",
}

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["config", "gt", "metrics", "model", "stage", "train", "weights"]


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"mamma_kit.landmarks.{_EXPORTS[name]}"), name)
    raise AttributeError(name)
