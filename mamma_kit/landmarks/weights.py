"""MammaNet weights: mamma-kit's own weight files, the embedded weights, the official checkpoint.

mamma-kit weight file (``.pt``, written by ``save_weights`` / `mamma-kit train`), a plain dict that
``torch.load(weights_only=True)`` reads::

    format        "mamma-kit/mammanet-weights/1"
    config        MammaNetConfig.to_dict()    (architecture: sizes travel with the weights)
    state_dict    {name: tensor}              (float32 or float16)
    landmark_set  str                         (which 512 surface points the outputs are)
    card          dict                        (training data, steps, metrics: the model card)

The embedded weights live in the package at ``mamma_kit/landmarks/weights/<arch>.pt`` with a model
card ``<arch>.md`` beside them. The official checkpoint is a PyTorch Lightning ``.ckpt`` whose
``state_dict`` holds the weights (architecture ``official``); it is read with weights_only=True and
mmap, and refused with a clear message if it needs arbitrary unpickling. Users point mamma-kit at it
with ``--weights`` or once for all with the environment variable ``MAMMA_KIT_MAMMANET_CKPT`` or
``[mammanet] checkpoint = "..."`` in ``~/.config/mamma-kit/official.toml`` (see ``official_paths``).
"""

from __future__ import annotations

import json
import os
import pickle
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import torch

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import atomic_path, read_toml, to_json
from mamma_kit.landmarks.config import CONFIGS, DEFAULT_ARCH, MammaNetConfig, get_config
from mamma_kit.landmarks.model import MammaNet, build_model

WEIGHTS_FORMAT = "mamma-kit/mammanet-weights/1"
EMBEDDED_DIR = Path(__file__).parent / "weights"
OFFICIAL_LANDMARK_SET = "official-smplx-512"
ENV_CKPT = "MAMMA_KIT_MAMMANET_CKPT"
ENV_VERTS = "MAMMA_KIT_LANDMARK_VERTS"
ENV_PARTS = "MAMMA_KIT_LANDMARK_PARTS"
ENV_CONFIG = "MAMMA_KIT_CONFIG_DIR"


@dataclass
class LoadedModel:
    model: MammaNet
    config: MammaNetConfig
    landmark_set: str
    source: str  # path of the weights
    trained: bool = True
    card: dict = field(default_factory=dict)


# ---- locations ---------------------------------------------------------------------------------
def embedded_weights_path(arch: str = DEFAULT_ARCH) -> Path:
    return EMBEDDED_DIR / f"{arch}.pt"


def user_config_path() -> Path:
    base = os.environ.get(ENV_CONFIG) or os.path.join(os.environ.get("XDG_CONFIG_HOME") or
                                                       os.path.expanduser("~/.config"), "mamma-kit")
    return Path(base) / "official.toml"


def official_paths() -> dict[str, Path | None]:
    """Configured official files: checkpoint, verts (512 x V landmark tensor), parts (body-part npz).

    Environment variables win over ``official.toml`` ([mammanet] checkpoint / verts / parts)."""
    cfg: dict = {}
    p = user_config_path()
    if p.is_file():
        cfg = read_toml(p, "mamma-kit user config").get("mammanet", {})
    out = {}
    for key, env in (("checkpoint", ENV_CKPT), ("verts", ENV_VERTS), ("parts", ENV_PARTS)):
        v = os.environ.get(env) or cfg.get(key)
        out[key] = Path(os.path.expanduser(str(v))) if v else None
    out["config_file"] = p if p.is_file() else None
    return out


# ---- reading ----------------------------------------------------------------------------------
def read_checkpoint(path: str | Path, what: str = "MammaNet weights") -> dict:
    """torch.load(weights_only=True) with one-line user errors for missing, pickled or corrupt files."""
    p = Path(path)
    if not p.exists():
        raise UserError(f"{what} not found: {p}", "check the path passed to --weights (or MAMMA_KIT_MAMMANET_CKPT)")
    if p.is_dir():
        raise UserError(f"{what} path is a folder: {p}", "pass the .ckpt/.pt file itself")
    mmap = zipfile.is_zipfile(p)
    try:
        obj = torch.load(p, map_location="cpu", weights_only=True, mmap=mmap)
    except pickle.UnpicklingError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise UserError(
            f"{p.name} needs unpickling of arbitrary Python objects, which mamma-kit refuses because it could run "
            f"code ({first[:120]})",
            "in a Python session you trust, re-save only the weights: "
            "torch.save({'state_dict': torch.load(p, weights_only=False)['state_dict']}, 'clean.ckpt'), "
            "then pass clean.ckpt") from None
    except (RuntimeError, EOFError, OSError, ValueError, zipfile.BadZipFile) as e:
        raise UserError(f"{p.name} is not a readable PyTorch checkpoint ({str(e).splitlines()[0][:120]})",
                        "download or copy the file again") from None
    if not isinstance(obj, dict):
        raise UserError(f"{p.name} holds a {type(obj).__name__}, not a checkpoint dict",
                        "pass a Lightning .ckpt (with 'state_dict') or a mamma-kit weights .pt")
    return obj


def state_dict_of(obj: dict, p: Path) -> dict[str, torch.Tensor]:
    """The tensors of a read checkpoint: its "state_dict" (without a Lightning "model." prefix) or
    the dict itself when it holds only tensors; UserError naming ``p`` when there are none."""
    sd = obj.get("state_dict", obj if all(isinstance(v, torch.Tensor) for v in obj.values()) else None)
    if not isinstance(sd, dict) or not sd:
        raise UserError(f"{p.name} has no 'state_dict' with weights", "pass a Lightning .ckpt or a mamma-kit .pt")
    keys = list(sd)
    if all(k.startswith("model.") for k in keys):  # a Lightning module that wraps the net as .model
        sd = {k[len("model."):]: v for k, v in sd.items()}
    return {k: v for k, v in sd.items() if isinstance(v, torch.Tensor)}


def _mismatch(model: MammaNet, sd: dict[str, torch.Tensor]) -> str:
    want = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    have = {k: tuple(v.shape) for k, v in sd.items()}
    missing = [k for k in want if k not in have]
    unexpected = [k for k in have if k not in want]
    shapes = [f"{k} {have[k]} vs {want[k]}" for k in want if k in have and have[k] != want[k]]
    parts = []
    if missing:
        parts.append(f"{len(missing)} missing (e.g. {missing[0]})")
    if unexpected:
        parts.append(f"{len(unexpected)} unexpected (e.g. {unexpected[0]})")
    if shapes:
        parts.append(f"{len(shapes)} with other shapes (e.g. {shapes[0]})")
    return ", ".join(parts)


def infer_arch(sd: dict[str, torch.Tensor]) -> str | None:
    """The named config whose state dict has exactly these names and shapes, if any."""
    from mamma_kit.landmarks.model import state_dict_shapes

    have = {k: tuple(v.shape) for k, v in sd.items()}
    n_lm = None
    q = have.get("decoder.query_embed.weight")
    if q is not None and q[0] > 1:
        n_lm = q[0]
    for name in CONFIGS:
        over = {"n_landmarks": n_lm} if n_lm and n_lm != CONFIGS[name].n_landmarks and "single" not in name else {}
        try:
            shapes = dict(state_dict_shapes(get_config(name, **over)))
        except UserError:
            continue
        if shapes == have:
            return name
    return None


def load_model(weights: str | Path | None = None, arch: str | None = None, device: str = "cpu") -> LoadedModel:
    """A MammaNet with weights, ready for inference (eval mode).

    - nothing given: the embedded weights (UserError if the package has none);
    - ``arch`` only: the package weights of that arch, or for ``official`` the configured checkpoint;
    - ``weights``: a mamma-kit .pt (its stored config; ``arch`` must agree) or a checkpoint holding a bare
      ``state_dict`` (Lightning .ckpt) whose architecture is ``arch`` or is recognised from its shapes.
    """
    if weights is None:
        name = arch or DEFAULT_ARCH
        if name.startswith("official"):
            configured = official_paths()["checkpoint"]
            if configured is None:
                raise UserError("no official MammaNet checkpoint configured",
                                f"pass --weights mamma_mask_full_cvpr.ckpt or set {ENV_CKPT}")
            weights = configured
        else:
            path = embedded_weights_path(name)
            if not path.is_file():
                raise UserError(
                    f"the embedded MammaNet weights ({name}) are not installed in this package ({path.name} missing)",
                    f"train them with `mamma-kit train mamma_kit/landmarks/configs/{name}.toml`, pass --weights PATH "
                    "(--arch official with the published checkpoint), or on a synthetic workspace use --source gt")
            weights = path
    p = Path(weights)
    obj = read_checkpoint(p)
    if obj.get("format") == WEIGHTS_FORMAT:
        cfg = MammaNetConfig.from_dict(obj["config"])
        if arch and arch != cfg.name and {**get_config(arch).to_dict(), "name": cfg.name} != cfg.to_dict():
            raise UserError(f"{p.name} holds a '{cfg.name}' MammaNet, not '{arch}'",
                            f"drop --arch (the file carries its architecture) or pass --arch {cfg.name}")
        landmark_set, card = str(obj.get("landmark_set", "")), dict(obj.get("card", {}))
    else:
        sd0 = state_dict_of(obj, p)
        name = arch or infer_arch(sd0)
        if name is None:
            raise UserError(f"{p.name} matches no known MammaNet architecture",
                            f"pass --arch (one of {', '.join(CONFIGS)}) to see what differs")
        cfg = get_config(name)
        landmark_set = OFFICIAL_LANDMARK_SET if name.startswith("official") else ""
        card = {}
    sd = obj["state_dict"] if obj.get("format") == WEIGHTS_FORMAT else state_dict_of(obj, p)
    with torch.device("meta"):  # no random init of weights that are about to be replaced
        model = MammaNet(cfg)
    diff = _mismatch(model, sd)
    if diff:
        raise UserError(f"{p.name} does not fit the '{cfg.name}' MammaNet architecture: {diff}",
                        "pass the matching --arch, or weights written by `mamma-kit train` (they carry their config)")
    # float32 compute; the (memory-mapped) checkpoint tensors become the parameters without a copy
    sd = {k: (v.float() if v.is_floating_point() and v.dtype != torch.float32 else v) for k, v in sd.items()}
    model.load_state_dict(sd, strict=True, assign=True)
    if any(b.is_meta for b in model.buffers()):
        # derived (non-persistent) buffers, e.g. the dense head's cell centres, are not in the
        # file: build those on the CPU (cheap for the models that have them)
        model = MammaNet(cfg)
        model.load_state_dict(sd, strict=True)
    model.eval().to(device)
    return LoadedModel(model, cfg, landmark_set, str(p.resolve()), True, card)


def random_model(arch: str = DEFAULT_ARCH, device: str = "cpu", seed: int = 0) -> LoadedModel:
    """Random weights of a named architecture (benchmarks and tests; outputs are meaningless)."""
    torch.manual_seed(seed)
    cfg = get_config(arch)
    return LoadedModel(build_model(cfg).eval().to(device), cfg, "", f"random:{arch}", trained=False)


def save_weights(path: str | Path, model: MammaNet, landmark_set: str = "", card: dict | None = None,
                 half: bool = False) -> Path:
    """Write a mamma-kit weight file atomically (float16 tensors with ``half`` to halve the size)."""
    sd = {k: (v.detach().cpu().half() if half and v.is_floating_point() else v.detach().cpu())
          for k, v in model.state_dict().items()}
    # the card goes through JSON so it holds only plain types (weights_only loading refuses others)
    obj = {"format": WEIGHTS_FORMAT, "config": model.cfg.to_dict(), "state_dict": sd,
           "landmark_set": str(landmark_set), "card": json.loads(to_json(card or {}))}
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)
    return Path(path)
