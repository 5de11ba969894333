"""MammaNet architecture configs: one dataclass, a few named sizes.

Every MammaNet in mamma-kit is built from a :class:`MammaNetConfig` by
:class:`mamma_kit.landmarks.model.MammaNet`. The named configs:

``official``
    The published checkpoint (shared/OFFICIAL-MAMMANET.md): ViT-B/16 at 512 x 384 (H x W), patch conv
    padding 2, 6-layer DETR decoder (d 768, 8 heads, FFN 2048) over 512 landmark queries, mask input.
    Its state dict has exactly the 282 names and shapes of the official Lightning checkpoint.
``embedded``
    The CPU default shipped in the package: d 128 at 192 x 144, a convolutional stem (in place of
    the single patch convolution) to 24 x 18 tokens, 4 encoder layers, 2 decoder layers over 512
    queries, mask input (also as a 4th channel of the stem), and a dense soft-argmax head whose
    positions the decoder refines without training the backbone (see ``dense_head``,
    ``mask_in_stem``, ``detach_decoder_memory``): these trade the paper's pretrained ViT-B, which a
    CPU cannot train, for inductive biases that learn from a few thousand synthetic crops in hours.
    The shipped weights add the layout visibility head (``layout_visibility``).
``embedded-kp``
    The keypoint-guided CPU default: 160 x 120 input, the conv stem reads the image, the target's
    mask, the other people's mask and Gaussian maps of BlazePose's 33 points of the target
    (``keypoints_in``, ``others_in_stem``); 3 encoder layers; no decoder: a keypoint prior (an MLP
    over the points in their own centre and scale) places the 512 landmarks and two rounds of
    features sampled around each landmark refine it and give its sigma, visibility and contacts
    (``head = "sampled"``). A network trained on a CPU on renders cannot learn to see people from
    pixels alone; the map from a real-world detector's points (plus mask and image) to dense
    surface landmarks it can learn, and that works on real people.
``embedded-256``
    A larger CPU model: d 192 at 256 x 192, patch 16, 6 encoder and 3 decoder layers.
``embedded-single`` / ``official-single``
    The single-query baseline (one learned token decodes all landmarks, as in CameraHMR) at the
    size of ``embedded`` / ``official``, for the paper's ablation.
``tiny`` / ``tiny-kp``
    For tests: d 32 at 64 x 48 (``tiny-kp``: keypoint-guided).

A config round-trips through a plain dict (stored with the weights and in training TOMLs).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from mamma_kit.core.errors import UserError


@dataclass(frozen=True)
class MammaNetConfig:
    """Sizes of a MammaNet. ``input_hw`` is (H, W) of the network input, 3:4 W:H."""

    name: str = "custom"
    input_hw: tuple[int, int] = (256, 192)
    # ViT backbone
    stem: str = "patch"  # "patch": one strided conv (ViT); "conv": 3x3 convs whose strides multiply to patch
    patch: int = 16
    patch_padding: int = 0
    dim: int = 192
    depth: int = 6
    heads: int = 3
    mlp_dim: int = 768
    vit_eps: float = 1e-6
    # mask embedding: Conv(1->c0, s0) LN GELU Conv(c0->c1, s1) LN GELU Conv(c1->dim, 1); s0 * s1 = patch
    use_mask: bool = True
    mask_channels: tuple[int, int] = (4, 16)
    mask_strides: tuple[int, int] = (4, 4)
    # DETR decoder
    queries: str = "per_landmark"  # or "single" (CameraHMR-style baseline)
    dec_layers: int = 3
    dec_heads: int = 4
    dec_ffn: int = 512
    dec_eps: float = 1e-5
    n_landmarks: int = 512
    # a dense head on the image tokens (one logit per token and landmark, soft-argmax over the
    # tokens) that the decoder's positions refine: trains in hours on a CPU where the decoder
    # alone converges slowly; not in the official architecture
    dense_head: bool = False
    # visibility from the layout of the predicted positions (landmarks/layout_vis.py) instead of
    # the decoder's output: fitted after training (`mamma-kit train --layout-visibility`)
    layout_visibility: bool = False
    # the mask also enters the conv stem as a 4th input channel (early fusion): the stem then sees
    # which pixels are the person from the first layer, instead of only after the transformer
    mask_in_stem: bool = False
    # the decoder reads the image tokens without training them (dense head configs): the backbone
    # then learns from the dense losses alone, whose per-cell signal is far cleaner on a short schedule
    detach_decoder_memory: bool = False
    # pre-processing: "official" d = max(box) / (2 * W_in); "scale" d = true downscale factor
    antialias: str = "scale"
    # keypoint guidance (keypoint-guided configs): the keypoint model's points of the target
    # (B, keypoints_in, 5: x, y normalised, z, visibility, presence) enter the conv stem as Gaussian
    # maps (sigma kp_map_sigma x input height); ``others_in_stem`` adds the other people's mask
    keypoints_in: int = 0
    kp_map_sigma: float = 0.025
    others_in_stem: bool = False
    # "detr": the paper's decoder over landmark queries; "sampled": positions from a keypoint prior
    # (an MLP in the keypoints' own centre and scale) refined ``refine_steps`` times from features
    # sampled around each landmark (no decoder; keypoint-guided configs only)
    head: str = "detr"
    refine_steps: int = 2
    head_channels: int = 64

    # ---- derived ----------------------------------------------------------------------
    @property
    def grid_hw(self) -> tuple[int, int]:
        """Token grid (rows, cols) of the patch conv."""
        h, w = self.input_hw
        p, pad = self.patch, self.patch_padding
        return (h + 2 * pad - p) // p + 1, (w + 2 * pad - p) // p + 1

    @property
    def n_tokens(self) -> int:
        gh, gw = self.grid_hw
        return gh * gw

    def validate(self) -> "MammaNetConfig":
        h, w = self.input_hw
        if h <= 0 or w <= 0 or abs(w / h - 0.75) > 0.02:
            raise UserError(f"MammaNet config {self.name}: input_hw {self.input_hw} must be H x W with W:H = 3:4",
                            "use e.g. [256, 192] or [512, 384]")
        if self.dim % self.heads or self.dim % self.dec_heads:
            raise UserError(f"MammaNet config {self.name}: dim {self.dim} not divisible by the head counts",
                            "pick heads / dec_heads that divide dim")
        if self.stem not in ("patch", "conv"):
            raise UserError(f"MammaNet config {self.name}: stem must be 'patch' or 'conv'")
        if self.stem == "conv" and (self.patch_padding or stem_strides(self.patch) is None):
            raise UserError(f"MammaNet config {self.name}: a conv stem needs patch = a product of 2s and 3s "
                            "and no patch padding")
        if self.mask_in_stem and (self.stem != "conv" or not self.use_mask):
            raise UserError(f"MammaNet config {self.name}: mask_in_stem needs stem = 'conv' and use_mask")
        if self.queries not in ("per_landmark", "single"):
            raise UserError(f"MammaNet config {self.name}: queries must be 'per_landmark' or 'single'")
        if self.head not in ("detr", "sampled"):
            raise UserError(f"MammaNet config {self.name}: head must be 'detr' or 'sampled'")
        if (self.keypoints_in or self.others_in_stem) and self.stem != "conv":
            raise UserError(f"MammaNet config {self.name}: keypoint maps and the others' mask need stem = 'conv'")
        if self.head == "sampled" and (not self.keypoints_in or self.dense_head or self.stem != "conv"):
            raise UserError(f"MammaNet config {self.name}: head = 'sampled' needs keypoints_in > 0, a conv stem "
                            "and no dense head")
        if self.antialias not in ("official", "scale"):
            raise UserError(f"MammaNet config {self.name}: antialias must be 'official' or 'scale'")
        if self.use_mask:
            s = self.mask_strides[0] * self.mask_strides[1]
            if (h // s, w // s) != self.grid_hw or h % s or w % s:
                raise UserError(f"MammaNet config {self.name}: mask embedding grid {(h // s, w // s)} differs "
                                f"from the patch grid {self.grid_hw}", "make mask_strides multiply to the patch size")
        return self

    # ---- dict round trip --------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, tuple):
                d[k] = list(v)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "MammaNetConfig":
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(d) - set(known))
        if unknown:
            raise UserError(f"unknown MammaNet config keys: {', '.join(unknown)}",
                            f"valid keys: {', '.join(known)}")
        kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()}
        return cls(**kw).validate()


def stem_strides(n: int) -> list[int] | None:
    """Strides of a conv stem for patch size n: 2s, then a 3 if needed (12 -> [2, 2, 3])."""
    out = []
    while n % 2 == 0 and n > 1:
        out.append(2)
        n //= 2
    while n % 3 == 0 and n > 1:
        out.append(3)
        n //= 3
    return out if n == 1 and out else None


OFFICIAL = MammaNetConfig(
    name="official", input_hw=(512, 384), patch=16, patch_padding=2, dim=768, depth=12, heads=12, mlp_dim=3072,
    use_mask=True, mask_channels=(4, 16), mask_strides=(4, 4), queries="per_landmark", dec_layers=6, dec_heads=8,
    dec_ffn=2048, n_landmarks=512, antialias="official",
)

EMBEDDED = MammaNetConfig(
    name="embedded", input_hw=(192, 144), stem="conv", patch=8, dim=128, depth=4, heads=4, mlp_dim=512,
    use_mask=True, mask_channels=(4, 16), mask_strides=(4, 2), dec_layers=2, dec_heads=4, dec_ffn=512,
    dense_head=True, mask_in_stem=True, detach_decoder_memory=True,
)

EMBEDDED_256 = MammaNetConfig(
    name="embedded-256", input_hw=(256, 192), patch=16, dim=192, depth=6, heads=3, mlp_dim=768,
    use_mask=True, mask_strides=(4, 4), dec_layers=3, dec_heads=4, dec_ffn=768,
)

# keypoint-guided: BlazePose's 33 points (and the other people's mask) as inputs, a keypoint prior
# refined from sampled image features; trains in about an hour on 2 CPU cores to a few % of the box
EMBEDDED_KP = MammaNetConfig(
    name="embedded-kp", input_hw=(160, 120), stem="conv", patch=8, dim=128, depth=3, heads=4, mlp_dim=512,
    use_mask=True, mask_channels=(4, 16), mask_strides=(4, 2), dec_layers=1, dec_heads=4, dec_ffn=256,
    mask_in_stem=True, keypoints_in=33, others_in_stem=True, head="sampled", head_channels=48,
)

TINY = MammaNetConfig(
    name="tiny", input_hw=(64, 48), patch=8, dim=32, depth=2, heads=2, mlp_dim=64, mask_strides=(4, 2),
    dec_layers=1, dec_heads=2, dec_ffn=64, n_landmarks=16,
)

CONFIGS: dict[str, MammaNetConfig] = {
    c.name: c for c in (
        OFFICIAL, EMBEDDED, EMBEDDED_KP, EMBEDDED_256, TINY,
        replace(TINY, name="tiny-kp", stem="conv", patch=8, mask_in_stem=True, keypoints_in=33,
                others_in_stem=True, head="sampled", head_channels=16),
        replace(EMBEDDED, name="embedded-single", queries="single"),
        replace(EMBEDDED, name="embedded-nomask", use_mask=False, mask_in_stem=False),
        replace(OFFICIAL, name="official-single", queries="single"),
        replace(TINY, name="tiny-single", queries="single"),
    )
}

DEFAULT_ARCH = "embedded-kp"


def get_config(name: str, **overrides: Any) -> MammaNetConfig:
    """A named config, optionally with fields overridden (``n_landmarks=16``)."""
    if name not in CONFIGS:
        raise UserError(f"unknown MammaNet architecture '{name}'", f"choose one of: {', '.join(CONFIGS)}")
    cfg = CONFIGS[name]
    if overrides:
        d = cfg.to_dict()
        d.update(overrides)
        cfg = MammaNetConfig.from_dict(d)
    return cfg.validate()
