"""`mamma-kit doctor` checks for MammaNet: embedded weights, and the official files if configured.

Official files are configured by environment variables (MAMMA_KIT_MAMMANET_CKPT, MAMMA_KIT_LANDMARK_VERTS,
MAMMA_KIT_LANDMARK_PARTS) or ``[mammanet] checkpoint / verts / parts`` in ~/.config/mamma-kit/official.toml
(or $MAMMA_KIT_CONFIG_DIR/official.toml). They are optional: the checks are marked so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mamma_kit.core.doctor import check as _check


def _embedded() -> dict:
    from mamma_kit.landmarks.config import DEFAULT_ARCH
    from mamma_kit.landmarks.weights import embedded_weights_path, read_checkpoint

    p = embedded_weights_path(DEFAULT_ARCH)
    fix = (f"train them: `mamma-kit train mamma_kit/landmarks/configs/{DEFAULT_ARCH}.toml`, copy the .pt and model "
           "card into mamma_kit/landmarks/weights/; meanwhile use --weights PATH or --source gt")
    if not p.is_file():
        return _check("MammaNet embedded weights", False, f"{p.name} not in the package", fix, optional=True)
    try:
        obj = read_checkpoint(p)
        card = obj.get("card", {})
        met = card.get("metrics") or {}
        detail = (f"{p.name} ({p.stat().st_size / 1e6:.1f} MB, {obj.get('config', {}).get('name')}, "
                  f"{card.get('training', {}).get('steps', '?')} steps, visible error "
                  f"{met.get('error_pct_box_visible', 'n/a')} % box height)")
        return _check("MammaNet embedded weights", True, detail)
    except Exception as e:  # noqa: BLE001 - report, never crash doctor
        return _check("MammaNet embedded weights", False, f"{p.name} unreadable: {e}", fix, optional=True)


def _official_checkpoint(path: Path) -> dict:
    from mamma_kit.landmarks.model import state_dict_shapes
    from mamma_kit.landmarks.weights import read_checkpoint, state_dict_of

    try:
        sd = state_dict_of(read_checkpoint(path, "official MammaNet checkpoint"), path)
    except Exception as e:  # noqa: BLE001
        return _check("official MammaNet checkpoint", False, str(e), "check MAMMA_KIT_MAMMANET_CKPT", optional=True)
    want = dict(state_dict_shapes("official"))
    have = {k: tuple(v.shape) for k, v in sd.items()}
    ok = have == want
    detail = (f"{path} ({len(have)} tensors, {sum(int(np.prod(s)) for s in have.values()):,} parameters"
              + (", matches the official architecture)" if ok else f", differs from the official {len(want)} tensors)"))
    return _check("official MammaNet checkpoint", ok, detail, "the file is not mamma_mask_full_cvpr.ckpt", optional=True)


def _official_landmarks(verts: Path | None, parts: Path | None) -> list[dict]:
    out = []
    if verts is not None:
        try:
            from mamma_kit.landmarks.weights import read_checkpoint  # noqa: F401 - same safe loader
            import torch

            if not verts.is_file():
                raise FileNotFoundError(f"not found: {verts}")
            t = torch.load(verts, map_location="cpu", weights_only=True)
            shape = tuple(t.shape) if hasattr(t, "shape") else None
            ok = shape is not None and len(shape) == 2 and shape[0] == 512
            out.append(_check("official landmark definition", ok,
                              f"{verts} {shape}" + (f" (512 landmarks over {shape[1]} vertices; needs the SMPL-X model "
                                                    f"with {shape[1]} vertices)" if ok else " (expected 512 x V)"),
                              "point MAMMA_KIT_LANDMARK_VERTS at verts_512.pkl", optional=True))
        except Exception as e:  # noqa: BLE001
            out.append(_check("official landmark definition", False, f"{verts}: {str(e).splitlines()[0][:160]}",
                              "point MAMMA_KIT_LANDMARK_VERTS at verts_512.pkl (a torch-saved tensor)", optional=True))
    if parts is not None:
        try:
            with np.load(parts, allow_pickle=False) as z:
                allidx = np.concatenate([z[k].ravel() for k in z.files])
            ok = np.array_equal(np.sort(allidx), np.arange(512))
            out.append(_check("official landmark body parts", ok,
                              f"{parts}: {len(allidx)} indices" + (" covering 0..511 once" if ok else " (not a partition of 0..511)"),
                              "point MAMMA_KIT_LANDMARK_PARTS at smplx_512_body_parts.npz", optional=True))
        except Exception as e:  # noqa: BLE001
            out.append(_check("official landmark body parts", False, f"{parts}: {e}",
                              "point MAMMA_KIT_LANDMARK_PARTS at smplx_512_body_parts.npz", optional=True))
    return out


def checks() -> list[dict]:
    from mamma_kit.landmarks.weights import official_paths

    out = [_embedded()]
    paths = official_paths()
    ck, verts, parts = paths["checkpoint"], paths["verts"], paths["parts"]
    if ck is None and verts is None and parts is None:
        out.append(_check("official MammaNet files", False, "not configured (optional)",
                          "set MAMMA_KIT_MAMMANET_CKPT (and MAMMA_KIT_LANDMARK_VERTS / _PARTS) or write "
                          "~/.config/mamma-kit/official.toml [mammanet] checkpoint/verts/parts", optional=True))
        return out
    if ck is not None:
        out.append(_official_checkpoint(ck))
    else:
        out.append(_check("official MammaNet checkpoint", False, "landmark files configured but no checkpoint",
                          "set MAMMA_KIT_MAMMANET_CKPT", optional=True))
    lm = _official_landmarks(verts, parts)
    out.extend(lm)
    if ck is not None and verts is None:
        out.append(_check("official landmark definition", False,
                          "checkpoint configured without verts_512: the fit cannot use the network's landmarks",
                          "set MAMMA_KIT_LANDMARK_VERTS", optional=True))
    return out
