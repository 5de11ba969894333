"""MammaNet in plain torch: ViT image features + mask embedding -> DETR decoder over landmark queries.

The module names follow the official checkpoint (shared/OFFICIAL-MAMMANET.md) so that the
``official`` config loads it strictly; smaller configs use the same classes at other sizes:

- ``backbone``: ViT. ``patch_embed.proj`` Conv2d(3, D, k=p, s=p, padding=pad) -> tokens (row-major);
  ``pos_embed`` (1, N + 1, D): token i gets ``pos_embed[i + 1] + pos_embed[0]`` (row 0 is a bias
  shared by every token; there is no class token); pre-norm ``blocks`` (LayerNorm eps 1e-6, qkv with
  bias, exact GELU, scale head_dim^-0.5) and ``last_norm``; output (B, D, gh, gw).
- ``mask_downscaling.mask_downscaling``: Conv(1->4, s4) LayerNorm2d GELU Conv(4->16, s4) LayerNorm2d GELU
  Conv(16->D, 1), summed with the backbone output *after* ``last_norm``.
- ``decoder``: ``decoder_detr`` post-norm DETR layers with sequence-first nn.MultiheadAttention
  (self-attn q = k = tgt + query_pos, v = tgt; cross-attn q = tgt + query_pos, k = memory + pos,
  v = memory, pos = pos_embed[1:]), a final ``norm``; target starts at zeros, queries are
  ``query_embed`` (L, D). Heads: ``landmarks`` MLP D -> D -> D -> 3 (x, y, log sigma; x, y in
  [-1, 1] over the crop), ``vis_prob``, ``contact_prob``, ``floor_contact_prob`` Linear(D, 1) logits.
- ``queries = "single"``: one learned token decodes all L landmarks (CameraHMR-style baseline);
  the heads then output 3L / L / L / L values from that token.
- keypoint-guided configs (``keypoints_in``, ``head = "sampled"``; not in the official checkpoint):
  the keypoint model's points enter the stem as Gaussian maps (``keypoint_maps``), ``prior`` places
  every landmark from the points (an MLP in the points' own centre and scale, so it does not have to
  learn translation and scale), and ``sampled`` refines each landmark from the image features sampled
  on a 3 x 3 grid around it, and predicts its sigma, visibility and contacts there.
"""

from __future__ import annotations

import math
from typing import TypedDict

import torch
import torch.nn.functional as F
from torch import nn

from mamma_kit.landmarks.config import MammaNetConfig


class MammaNetOutput(TypedDict, total=False):
    xy: torch.Tensor  # (B, L, 2) normalised crop coordinates in [-1, 1]
    xy_dense: torch.Tensor  # (B, L, 2) the dense head's soft-argmax (configs with dense_head)
    dense_logits: torch.Tensor  # (B, N, L) its logits per token (training only)
    dense_centres: torch.Tensor  # (N, 2) the tokens' centres, normalised (training only)
    log_sigma: torch.Tensor  # (B, L) log sigma in normalised units (1 = half the crop width / height)
    vis_logit: torch.Tensor  # (B, L)
    contact_logit: torch.Tensor  # (B, L)
    floor_logit: torch.Tensor  # (B, L)
    xy_prior: torch.Tensor  # (B, L, 2) the keypoint prior's positions (sampled head)
    vis_logit_prior: torch.Tensor  # (B, L) its visibility logits (sampled head)
    floor_logit_prior: torch.Tensor  # (B, L) its floor-contact logits (sampled head)


# ---- backbone ------------------------------------------------------------------------------
def stem_channels(cfg: MammaNetConfig) -> int:
    """Input channels of the conv stem: RGB, then the mask, the others' mask, the keypoint maps."""
    return 3 + int(cfg.mask_in_stem) + int(cfg.others_in_stem) + cfg.keypoints_in
class PatchEmbed(nn.Module):
    def __init__(self, cfg: MammaNetConfig):
        super().__init__()
        self.proj = nn.Conv2d(3, cfg.dim, kernel_size=cfg.patch, stride=cfg.patch, padding=cfg.patch_padding)

    def forward(self, x_b3hw: torch.Tensor) -> tuple[torch.Tensor, None]:
        return self.proj(x_b3hw), None  # (B, D, gh, gw), no finer map


class ConvStem(nn.Module):
    """Stages of two 3x3 convolutions (LayerNorm2d, GELU; the second residual), the first of
    each strided, whose strides multiply to the patch size, widening to the token dimension: a
    ViT trained from scratch on little data learns locality far faster with it than from one
    patch-sized convolution. Output (B, D, gh, gw) like PatchEmbed, and the features of the stage
    before the last (twice the token resolution) for the dense head."""

    def __init__(self, cfg: MammaNetConfig):
        super().__init__()
        from mamma_kit.landmarks.config import stem_strides

        strides = stem_strides(cfg.patch)
        widths = [max(16, cfg.dim >> (len(strides) - 1 - i)) for i in range(len(strides))]
        self.down = nn.ModuleList()
        self.refine = nn.ModuleList()
        c = stem_channels(cfg)
        for st, w in zip(strides, widths):
            k = 3 if st == 2 else st
            self.down.append(nn.Sequential(nn.Conv2d(c, w, k, stride=st, padding=1 if st == 2 else 0),
                                           LayerNorm2d(w, cfg.vit_eps), nn.GELU()))
            self.refine.append(nn.Sequential(nn.Conv2d(w, w, 3, padding=1), LayerNorm2d(w, cfg.vit_eps), nn.GELU()))
            c = w
        self.fine_channels = widths[-2] if len(widths) > 1 else widths[-1]

    def forward(self, x_bchw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (B, stem_channels(cfg), H, W): image, then mask / others / keypoint maps as configured."""
        x, fine = x_bchw, None
        for i, (d, r) in enumerate(zip(self.down, self.refine)):
            x = d(x)
            x = x + r(x)
            if i == len(self.down) - 2:
                fine = x
        return x, (fine if fine is not None else x)


class Attention(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim, bias=True)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x_bnd: torch.Tensor) -> torch.Tensor:
        B, N, D = x_bnd.shape
        qkv = self.qkv(x_bnd).reshape(B, N, 3, self.heads, D // self.heads).permute(2, 0, 3, 1, 4)
        # default scale of scaled_dot_product_attention is head_dim ** -0.5
        o = F.scaled_dot_product_attention(qkv[0], qkv[1], qkv[2])
        return self.proj(o.transpose(1, 2).reshape(B, N, D))


class Mlp(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(F.gelu(self.fc1(x)))


class Block(nn.Module):
    """Pre-norm transformer block."""

    def __init__(self, cfg: MammaNetConfig):
        super().__init__()
        self.norm1 = nn.LayerNorm(cfg.dim, eps=cfg.vit_eps)
        self.attn = Attention(cfg.dim, cfg.heads)
        self.norm2 = nn.LayerNorm(cfg.dim, eps=cfg.vit_eps)
        self.mlp = Mlp(cfg.dim, cfg.mlp_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class ViT(nn.Module):
    def __init__(self, cfg: MammaNetConfig):
        super().__init__()
        self.grid_hw = cfg.grid_hw
        self.patch_embed = PatchEmbed(cfg) if cfg.stem == "patch" else ConvStem(cfg)
        self.pos_embed = nn.Parameter(torch.zeros(1, cfg.n_tokens + 1, cfg.dim))
        self.blocks = nn.ModuleList(Block(cfg) for _ in range(cfg.depth))
        self.last_norm = nn.LayerNorm(cfg.dim, eps=cfg.vit_eps)

    def forward(self, x_bchw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(B, 3 or 4, H, W) -> tokens (B, D, gh, gw) and the stem's finer map (conv stem) or None."""
        f, fine = self.patch_embed(x_bchw)
        B, D, gh, gw = f.shape
        if (gh, gw) != self.grid_hw:
            raise ValueError(f"input gives a {gh}x{gw} token grid, the model expects {self.grid_hw}")
        x = f.flatten(2).transpose(1, 2)  # (B, N, D), row-major tokens
        x = x + self.pos_embed[:, 1:] + self.pos_embed[:, :1]
        for blk in self.blocks:
            x = blk(x)
        x = self.last_norm(x)
        return x.transpose(1, 2).reshape(B, D, gh, gw), fine


# ---- mask embedding ----------------------------------------------------------------------------
class LayerNorm2d(nn.Module):
    """LayerNorm over the channel dimension of (B, C, H, W)."""

    def __init__(self, channels: int, eps: float = 1e-6):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))
        self.eps = eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        u = x.mean(1, keepdim=True)
        s = (x - u).pow(2).mean(1, keepdim=True)
        x = (x - u) / torch.sqrt(s + self.eps)
        return self.weight[:, None, None] * x + self.bias[:, None, None]


class MaskEmbed(nn.Module):
    def __init__(self, cfg: MammaNetConfig):
        super().__init__()
        c0, c1 = cfg.mask_channels
        s0, s1 = cfg.mask_strides
        self.mask_downscaling = nn.Sequential(
            nn.Conv2d(1, c0, kernel_size=s0, stride=s0), LayerNorm2d(c0, cfg.vit_eps), nn.GELU(),
            nn.Conv2d(c0, c1, kernel_size=s1, stride=s1), LayerNorm2d(c1, cfg.vit_eps), nn.GELU(),
            nn.Conv2d(c1, cfg.dim, kernel_size=1),
        )

    def forward(self, mask_b1hw: torch.Tensor) -> torch.Tensor:
        return self.mask_downscaling(mask_b1hw)


# ---- decoder -------------------------------------------------------------------------------------
class DecoderLayer(nn.Module):
    """DETR decoder layer, post-norm, sequence-first (S, B, D) tensors."""

    def __init__(self, cfg: MammaNetConfig):
        super().__init__()
        d = cfg.dim
        self.self_attn = nn.MultiheadAttention(d, cfg.dec_heads)
        self.multihead_attn = nn.MultiheadAttention(d, cfg.dec_heads)
        self.linear1 = nn.Linear(d, cfg.dec_ffn)
        self.linear2 = nn.Linear(cfg.dec_ffn, d)
        self.norm1 = nn.LayerNorm(d, eps=cfg.dec_eps)
        self.norm2 = nn.LayerNorm(d, eps=cfg.dec_eps)
        self.norm3 = nn.LayerNorm(d, eps=cfg.dec_eps)

    def forward(self, tgt: torch.Tensor, memory: torch.Tensor, pos: torch.Tensor,
                query_pos: torch.Tensor) -> torch.Tensor:
        q = tgt + query_pos
        tgt = self.norm1(tgt + self.self_attn(q, q, tgt, need_weights=False)[0])
        tgt2 = self.multihead_attn(tgt + query_pos, memory + pos, memory, need_weights=False)[0]
        tgt = self.norm2(tgt + tgt2)
        return self.norm3(tgt + self.linear2(F.gelu(self.linear1(tgt))))


class DetrDecoder(nn.Module):
    def __init__(self, cfg: MammaNetConfig):
        super().__init__()
        self.layers = nn.ModuleList(DecoderLayer(cfg) for _ in range(cfg.dec_layers))
        self.norm = nn.LayerNorm(cfg.dim, eps=cfg.dec_eps)

    def forward(self, tgt, memory, pos, query_pos) -> torch.Tensor:
        for layer in self.layers:
            tgt = layer(tgt, memory, pos, query_pos)
        return self.norm(tgt)  # only the last layer's output is used


class MLP(nn.Module):
    def __init__(self, dim_in: int, hidden: int, dim_out: int, n_layers: int = 3):
        super().__init__()
        dims = [dim_in] + [hidden] * (n_layers - 1) + [dim_out]
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = F.relu(x)
        return x


class LandmarkDecoder(nn.Module):
    def __init__(self, cfg: MammaNetConfig):
        super().__init__()
        self.single = cfg.queries == "single"
        L, d = cfg.n_landmarks, cfg.dim
        per = L if self.single else 1  # values per query
        self.n_landmarks = L
        self.query_embed = nn.Embedding(1 if self.single else L, d)
        self.decoder_detr = DetrDecoder(cfg)
        self.landmarks = MLP(d, d, 3 * per)
        self.vis_prob = nn.Linear(d, per)
        self.contact_prob = nn.Linear(d, per)
        self.floor_contact_prob = nn.Linear(d, per)

    def forward(self, memory_bdhw: torch.Tensor, pos_1nd: torch.Tensor,
                xy_base: torch.Tensor | None = None) -> MammaNetOutput:
        """``xy_base`` (B, L, 2): positions the decoder's outputs are offsets to (dense head)."""
        B = memory_bdhw.shape[0]
        memory = memory_bdhw.flatten(2).permute(2, 0, 1)  # (N, B, D)
        pos = pos_1nd.transpose(0, 1)  # (N, 1, D)
        query_pos = self.query_embed.weight[:, None, :].expand(-1, B, -1)  # (Q, B, D)
        hs = self.decoder_detr(torch.zeros_like(query_pos), memory, pos, query_pos).transpose(0, 1)  # (B, Q, D)
        L = self.n_landmarks
        lm = self.landmarks(hs).reshape(B, L, 3)
        return MammaNetOutput(
            xy=lm[..., :2] if xy_base is None else xy_base + lm[..., :2], log_sigma=lm[..., 2],
            vis_logit=self.vis_prob(hs).reshape(B, L),
            contact_logit=self.contact_prob(hs).reshape(B, L),
            floor_logit=self.floor_contact_prob(hs).reshape(B, L),
        )


class DenseHead(nn.Module):
    """Per landmark, a logit on every cell of a map; the landmark is the softmax-weighted mean
    of the cells' centres (integral regression). Dense supervision of every cell teaches the
    backbone where each landmark is far faster than the decoder's cross-attention learns it.
    With a conv stem the map is the stem's finer stage (twice the token resolution) fused with
    the upsampled tokens; else the token grid itself."""

    def __init__(self, cfg: MammaNetConfig, fine_channels: int | None = None):
        super().__init__()
        gh, gw = cfg.grid_hw
        h, w = cfg.input_hw
        p, pad = cfg.patch, cfg.patch_padding
        self.fine = fine_channels is not None
        if self.fine:
            c = fine_channels
            self.from_tokens = nn.Conv2d(cfg.dim, c, 1)
            self.from_fine = nn.Conv2d(c, c, 1)
            self.mix = nn.Sequential(nn.GELU(), nn.Conv2d(c, c, 3, padding=1), nn.GELU())
            self.logits = nn.Conv2d(c, cfg.n_landmarks, 1)
            gh, gw, p = 2 * gh, 2 * gw, p / 2
        else:
            self.logits = nn.Linear(cfg.dim, cfg.n_landmarks)
        # cell centres in normalised crop units: cell c spans input px [c p - pad, (c + 1) p - pad)
        # on the CPU even where the model is built on the meta device (weights.load_model): the
        # checkpoint does not hold these
        cx = ((torch.arange(gw, device="cpu") + 0.5) * p - pad) / w * 2 - 1
        cy = ((torch.arange(gh, device="cpu") + 0.5) * p - pad) / h * 2 - 1
        yy, xx = torch.meshgrid(cy, cx, indexing="ij")
        self.register_buffer("centres_n2", torch.stack([xx, yy], -1).reshape(-1, 2), persistent=False)

    def forward(self, memory_bdhw: torch.Tensor, fine_bchw: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """-> positions (B, L, 2) and the logits (B, N, L) (the training loss sharpens them)."""
        if self.fine:
            up = F.interpolate(self.from_tokens(memory_bdhw), size=fine_bchw.shape[-2:], mode="bilinear",
                               align_corners=False)
            logits = self.logits(self.mix(up + self.from_fine(fine_bchw))).flatten(2).transpose(1, 2)
        else:
            logits = self.logits(memory_bdhw.flatten(2).transpose(1, 2))  # (B, N, L)
        prob = torch.softmax(logits, dim=1)  # over the cells
        return torch.einsum("bnl,nc->blc", prob, self.centres_n2), logits


# ---- keypoint guidance -----------------------------------------------------------------------------
def keypoint_maps(kp_bp5: torch.Tensor, hw: tuple[int, int], sigma_frac: float) -> torch.Tensor:
    """(B, P, H, W) Gaussian maps of the points (B, P, 5: x, y normalised, z, visibility, presence),
    sigma ``sigma_frac`` x H px; a point's peak is 0.3 + 0.7 visibility, 0 where the point is absent."""
    H, W = hw
    s = sigma_frac * H
    x = (kp_bp5[..., 0] + 1) * (W / 2) - 0.5  # (B, P) input px, pixel-centre convention
    y = (kp_bp5[..., 1] + 1) * (H / 2) - 0.5
    amp = (kp_bp5[..., 4] > 0).to(kp_bp5.dtype) * (0.3 + 0.7 * kp_bp5[..., 3].clamp(0, 1))
    xs = torch.arange(W, dtype=kp_bp5.dtype, device=kp_bp5.device)
    ys = torch.arange(H, dtype=kp_bp5.dtype, device=kp_bp5.device)
    gx = torch.exp(-0.5 * ((xs - x[..., None]) / s) ** 2)  # (B, P, W)
    gy = torch.exp(-0.5 * ((ys - y[..., None]) / s) ** 2) * amp[..., None]  # (B, P, H)
    return gy[..., :, None] * gx[..., None, :]


def keypoint_frame(kp_bp5: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Centre (B, 1, 2) and scale (B, 1, 1) of the present points (normalised crop units); the crop's
    centre and 0.5 where no point is present."""
    w = (kp_bp5[..., 4:5] > 0).to(kp_bp5.dtype)  # (B, P, 1)
    n = w.sum(1, keepdim=True)
    c = (kp_bp5[..., :2] * w).sum(1, keepdim=True) / n.clamp_min(1)
    r2 = (((kp_bp5[..., :2] - c) ** 2).sum(-1, keepdim=True) * w).sum(1, keepdim=True) / n.clamp_min(1)
    has = (n >= 3).to(kp_bp5.dtype)
    scale = has * r2.sqrt().clamp_min(0.05) + (1 - has) * 0.5
    return c * has, scale


class KeypointPrior(nn.Module):
    """Landmark positions (and visibility and floor-contact logits) from the points alone, in the
    points' own centre and scale: it reads no pixels, so it can be trained first on the crops'
    (points, landmarks) pairs in minutes (train.pretrain_prior) before the image network learns what
    the pixels add. Which side of the body faces the camera and which foot bears the weight are
    in the points' layout; person contact is not (the refinement sees the other people's mask)."""

    def __init__(self, cfg: MammaNetConfig, hidden: int = 512):
        super().__init__()
        P, L = cfg.keypoints_in, cfg.n_landmarks
        self.net = nn.Sequential(nn.Linear(5 * P, hidden), nn.GELU(), nn.Linear(hidden, hidden), nn.GELU())
        self.xy = nn.Linear(hidden, 2 * L)
        self.logits = nn.Linear(hidden, 2 * L)  # visibility, floor contact
        self.code = nn.Linear(hidden, cfg.head_channels)

    def forward(self, kp_bp5: torch.Tensor) -> dict[str, torch.Tensor]:
        """-> xy (B, L, 2) normalised, vis_logit / floor_logit (B, L), code (B, C) for the refinement."""
        c, s = keypoint_frame(kp_bp5)
        present = (kp_bp5[..., 4:5] > 0).to(kp_bp5.dtype)
        local = torch.cat([(kp_bp5[..., :2] - c) / s * present, kp_bp5[..., 2:3] / s * present, kp_bp5[..., 3:5]], -1)
        h = self.net(local.flatten(1))
        B = kp_bp5.shape[0]
        lg = self.logits(h).reshape(B, -1, 2)
        return {"xy": c + s * self.xy(h).reshape(B, -1, 2), "vis_logit": lg[..., 0], "floor_logit": lg[..., 1],
                "code": self.code(h)}


class SampledHead(nn.Module):
    """Refines positions from features sampled around them; sigma, visibility and contacts too.

    The feature map is the conv stem's finer stage fused with the upsampled tokens (as the dense
    head's). Each of ``refine_steps`` rounds samples a 3 x 3 grid (one fine cell apart) around every
    landmark and moves it; the last round's MLP also gives log sigma and the three logits."""

    def __init__(self, cfg: MammaNetConfig, fine_channels: int):
        super().__init__()
        C, L = cfg.head_channels, cfg.n_landmarks
        self.from_tokens = nn.Conv2d(cfg.dim, C, 1)
        self.from_fine = nn.Conv2d(fine_channels, C, 1)
        self.mix = nn.Sequential(nn.GELU(), nn.Conv2d(C, C, 3, padding=1), nn.GELU())
        self.embed = nn.Embedding(L, C)
        gh, gw = cfg.grid_hw
        # the 3 x 3 sampling grid, one fine cell (half a token) apart, in normalised units
        d = torch.tensor([-1.0, 0.0, 1.0], device="cpu")  # built on the CPU, as centres_n2
        yy, xx = torch.meshgrid(d / gh, d / gw, indexing="ij")
        self.register_buffer("grid_k2", torch.stack([xx, yy], -1).reshape(-1, 2), persistent=False)
        n_in = 9 * C + 2 * C + 2
        self.rounds = nn.ModuleList(MLP(n_in, 2 * C, 6 if i == cfg.refine_steps - 1 else 2, 3)
                                    for i in range(cfg.refine_steps))

    def feature_map(self, memory_bdhw: torch.Tensor, fine_bchw: torch.Tensor) -> torch.Tensor:
        up = F.interpolate(self.from_tokens(memory_bdhw), size=fine_bchw.shape[-2:], mode="bilinear",
                           align_corners=False)
        return self.mix(up + self.from_fine(fine_bchw))

    def forward(self, fmap_bchw: torch.Tensor, prior: dict[str, torch.Tensor]) -> MammaNetOutput:
        """Refines the prior's positions (not training the prior: it learns from its own loss, which
        the position NLL's far larger gradient would swamp) and its visibility / floor logits."""
        xy_bl2, code_bc = prior["xy"].detach(), prior["code"]
        B, L = xy_bl2.shape[:2]
        K = self.grid_k2.shape[0]
        emb = self.embed.weight[None].expand(B, -1, -1)
        code = code_bc[:, None].expand(-1, L, -1)
        xy = xy_bl2
        for i, mlp in enumerate(self.rounds):
            at = xy.detach()
            pts = (at[:, :, None, :] + self.grid_k2).reshape(B, L * K, 1, 2)  # x, y in [-1, 1]
            f = F.grid_sample(fmap_bchw, pts, mode="bilinear", padding_mode="zeros", align_corners=False)
            f = f[..., 0].reshape(B, -1, L, K).permute(0, 2, 3, 1).reshape(B, L, -1)  # (B, L, K C)
            o = mlp(torch.cat([f, emb, code, at], -1))
            xy = xy + o[..., :2]
        return MammaNetOutput(xy=xy, log_sigma=o[..., 2] + math.log(0.05),
                              vis_logit=prior["vis_logit"].detach() + o[..., 3], contact_logit=o[..., 4],
                              floor_logit=prior["floor_logit"].detach() + o[..., 5])


# ---- the network ----------------------------------------------------------------------------------
class MammaNet(nn.Module):
    """Dense landmark network; ``forward(image, mask)`` -> :class:`MammaNetOutput`.

    image: (B, 3, H, W) float, RGB normalised with ImageNet mean/std (crop.normalise_images);
    mask: (B, 1, H, W) float {0, 1} of the target person, or None (a zero mask; ignored by
    configs with ``use_mask = False``).
    """

    def __init__(self, cfg: MammaNetConfig):
        super().__init__()
        self.cfg = cfg.validate()
        self.backbone = ViT(cfg)
        self.decoder = LandmarkDecoder(cfg) if cfg.head == "detr" else None
        self.mask_downscaling = MaskEmbed(cfg) if cfg.use_mask else None
        fine = self.backbone.patch_embed.fine_channels if cfg.stem == "conv" else None
        self.dense = DenseHead(cfg, fine) if cfg.dense_head else None
        self.prior = KeypointPrior(cfg) if cfg.head == "sampled" else None
        self.sampled = SampledHead(cfg, fine) if cfg.head == "sampled" else None
        self.layout_vis = None
        if cfg.layout_visibility:
            from mamma_kit.landmarks.layout_vis import LayoutVisibility

            self.layout_vis = LayoutVisibility(cfg.n_landmarks)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.LayerNorm):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        for mod in self.modules():
            if isinstance(mod, nn.MultiheadAttention):
                nn.init.xavier_uniform_(mod.in_proj_weight)
                nn.init.zeros_(mod.in_proj_bias)
        nn.init.trunc_normal_(self.backbone.pos_embed, std=0.02)
        if self.decoder is not None:
            nn.init.normal_(self.decoder.query_embed.weight, std=1.0)
            # start at the crop centre with sigma = 0.2 crop half-widths
            last = self.decoder.landmarks.layers[-1]
            nn.init.zeros_(last.weight)
            with torch.no_grad():
                last.bias.view(-1, 3)[:, 2] = math.log(0.2)
        if self.sampled is not None:  # refinements start at zero: the prior's positions
            for mlp in self.sampled.rounds:
                nn.init.zeros_(mlp.layers[-1].weight)
                nn.init.zeros_(mlp.layers[-1].bias)

    @property
    def n_landmarks(self) -> int:
        return self.cfg.n_landmarks

    def features(self, image: torch.Tensor, mask: torch.Tensor | None = None, keypoints: torch.Tensor | None = None,
                 others: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """-> image tokens with the mask embedding (B, D, gh, gw), and the stem's finer map or None."""
        cfg = self.cfg
        zeros = image.new_zeros(image.shape[0], 1, *image.shape[2:])
        if self.mask_downscaling is not None and mask is None:
            mask = zeros
        x = [image]
        if cfg.mask_in_stem:
            x.append(mask)
        if cfg.others_in_stem:
            x.append(zeros if others is None else others)
        if cfg.keypoints_in:
            x.append(keypoint_maps(self.keypoints_or_none(keypoints, image), cfg.input_hw, cfg.kp_map_sigma))
        f, fine = self.backbone(torch.cat(x, 1) if len(x) > 1 else image)
        if self.mask_downscaling is not None:
            f = f + self.mask_downscaling(mask)
        return f, fine

    def keypoints_or_none(self, keypoints: torch.Tensor | None, image: torch.Tensor) -> torch.Tensor:
        """The keypoints, or all-absent points (B, P, 5) zeros where a crop has none."""
        if keypoints is None:
            return image.new_zeros(image.shape[0], self.cfg.keypoints_in, 5)
        return keypoints

    def forward(self, image: torch.Tensor, mask: torch.Tensor | None = None, keypoints: torch.Tensor | None = None,
                others: torch.Tensor | None = None) -> MammaNetOutput:
        """``keypoints`` (B, P, 5) and ``others`` (B, 1, H, W): keypoint-guided configs only."""
        out = self._forward(image, mask, keypoints, others)
        if self.layout_vis is not None:
            H, W = self.cfg.input_hw
            half = out["xy"].new_tensor([W / 2, H / 2])  # normalised -> input-crop px
            out["vis_logit"] = self.layout_vis(out["xy"].detach() * half)
        return out

    def _forward(self, image, mask=None, keypoints=None, others=None) -> MammaNetOutput:
        f, fine = self.features(image, mask, keypoints, others)
        if self.sampled is not None:
            prior = self.prior(self.keypoints_or_none(keypoints, image))
            out = self.sampled(self.sampled.feature_map(f, fine), prior)
            out["xy_prior"] = prior["xy"]
            out["vis_logit_prior"] = prior["vis_logit"]
            out["floor_logit_prior"] = prior["floor_logit"]
            return out
        if self.dense is None:
            return self.decoder(f, self.backbone.pos_embed[:, 1:])
        xy_dense, logits = self.dense(f, fine)
        # the decoder refines the dense positions but does not train them: the dense head learns
        # from its own (dense) losses only, which the position NLL's far larger gradient would swamp
        memory = f.detach() if self.cfg.detach_decoder_memory else f
        out = self.decoder(memory, self.backbone.pos_embed[:, 1:], xy_base=xy_dense.detach())
        out["xy_dense"] = xy_dense
        if self.training:
            out["dense_logits"] = logits
            out["dense_centres"] = self.dense.centres_n2
        return out


def build_model(cfg: MammaNetConfig | str, device: str | torch.device = "cpu", **overrides) -> MammaNet:
    """A MammaNet with random weights from a config or a config name (``"embedded"``)."""
    from mamma_kit.landmarks.config import get_config

    if isinstance(cfg, str):
        cfg = get_config(cfg, **overrides)
    return MammaNet(cfg).to(device)


def state_dict_shapes(cfg: MammaNetConfig | str) -> list[tuple[str, tuple[int, ...]]]:
    """(name, shape) of every state-dict tensor, without allocating the weights."""
    with torch.device("meta"):
        model = build_model(cfg, device="meta")
    return [(k, tuple(v.shape)) for k, v in model.state_dict().items()]


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
