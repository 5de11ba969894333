"""The crop contract: person mask/box -> fixed-aspect network input, and outputs back to image pixels.

Pixel coordinates follow OpenCV (integer = pixel centre), in the image and in the crop.

1. Box: the tight min/max of the mask's non-zero pixel indices (``mask_box``; a masks/<cam>.npz
   box x1, y1, x2, y2 with exclusive x2, y2 maps to x2 - 1, y2 - 1: ``tight_box_from_track_box``).
2. Expand (``expand_box``): centre = mid-point, size (x2 - x1, y2 - y1) x 1.2, then grown (never
   shrunk) to W:H = 3:4. The result is a :class:`numpy` array ``box_n4`` = (cx, cy, bw, bh).
3. Warp (``crop_affine``/``warp_crop``): the box's continuous extent [cx - bw/2, cx + bw/2] maps onto the
   crop's continuous extent [-0.5, W_in - 0.5] (likewise y), i.e. crop pixel u has its centre at image
   x = cx + (u + 0.5 - W_in/2) * bw / W_in. Image bilinear, mask nearest, border 0. When the crop
   downscales, the crop REGION of the image (never the whole frame) is Gaussian-blurred first with
   sigma (d - 1) / 2 if d > 1.1, where d = max(bw, bh) / (2 W_in) for the ``official`` rule (as in
   the official pre-processing) and d = bh / H_in, the true downscale factor, for our own models
   (``scale`` rule; there the region is first halved k = floor(log2 d) times with an image pyramid
   and the remaining factor d / 2^k is blurred the same way, so a 4K frame costs a few ms).
4. Network coordinates n in [-1, 1] span the box: n = -1 and +1 are its left/right (top/bottom)
   edges, so image x = cx + n_x * bw / 2, y = cy + n_y * bh / 2 (``normalised_to_image``), and crop
   pixel u = (n + 1) / 2 * W_in - 0.5.
5. Sigma: the network's third channel is log sigma in normalised units, one unit = half the box
   (192 / 256 crop px for the official 384 x 512 input). We treat it as log sigma (not log-variance,
   which the official fitter assumed) and convert per axis: sigma_x = exp(s) * bw / 2 and
   sigma_y = exp(s) * bh / 2 image px (``sigma_to_pixels``).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], np.float32) * 255.0
IMAGENET_STD = np.array([0.229, 0.224, 0.225], np.float32) * 255.0
BOX_SCALE = 1.2
ASPECT_WH = 0.75


# ---- boxes ------------------------------------------------------------------------------
def mask_box(mask_hw: np.ndarray) -> np.ndarray | None:
    """(4,) float64 tight box x1, y1, x2, y2 = min/max pixel indices of the mask, or None if empty."""
    rows = np.flatnonzero(mask_hw.any(1))
    if not len(rows):
        return None
    cols = np.flatnonzero(mask_hw.any(0))
    return np.array([cols[0], rows[0], cols[-1], rows[-1]], np.float64)


def tight_box_from_track_box(box_n4: np.ndarray) -> np.ndarray:
    """masks/<cam>.npz boxes (exclusive x2, y2) -> min/max pixel indices as in ``mask_box``."""
    b = np.asarray(box_n4, np.float64).copy()
    b[..., 2:] -= 1.0
    return b


def expand_box(box_n4: np.ndarray, scale: float = BOX_SCALE, aspect_wh: float = ASPECT_WH,
               min_size: float = 1.0) -> np.ndarray:
    """Tight boxes (..., 4) x1, y1, x2, y2 -> crop boxes (..., 4) cx, cy, bw, bh: x scale, grown to W:H."""
    b = np.asarray(box_n4, np.float64)
    cx, cy = (b[..., 0] + b[..., 2]) / 2, (b[..., 1] + b[..., 3]) / 2
    w = np.maximum((b[..., 2] - b[..., 0]) * scale, min_size)
    h = np.maximum((b[..., 3] - b[..., 1]) * scale, min_size)
    bw = np.maximum(w, h * aspect_wh)
    bh = np.maximum(h, w / aspect_wh)
    return np.stack([cx, cy, bw, bh], -1)


def crop_affine(box_4: np.ndarray, out_wh: tuple[int, int], rot_rad: float = 0.0) -> np.ndarray:
    """(2, 3) affine image px -> crop px of one crop box (cx, cy, bw, bh), optional rotation
    about the box centre (content turns by +rot in the crop; training augmentation only)."""
    cx, cy, bw, bh = (float(v) for v in box_4)
    W, H = out_wh
    sx, sy = W / bw, H / bh
    c, s = math.cos(rot_rad), math.sin(rot_rad)
    # u = sx * (c*(x-cx) - s*(y-cy)) + W/2 - 0.5 ; v = sy * (s*(x-cx) + c*(y-cy)) + H/2 - 0.5
    A = np.array([[sx * c, -sx * s], [sy * s, sy * c]])
    t = np.array([W / 2 - 0.5, H / 2 - 0.5]) - A @ np.array([cx, cy])
    return np.concatenate([A, t[:, None]], 1)


def apply_affine(M_23: np.ndarray, xy_n2: np.ndarray) -> np.ndarray:
    xy = np.asarray(xy_n2, np.float64)
    return xy @ M_23[:, :2].T + M_23[:, 2]


def invert_affine(M_23: np.ndarray) -> np.ndarray:
    return cv2.invertAffineTransform(np.asarray(M_23, np.float64))


def antialias_sigma(box_4: np.ndarray, out_wh: tuple[int, int], rule: str = "scale") -> float:
    """Gaussian sigma (image px) to blur the crop region before warping; 0 = no blur."""
    bw, bh = float(box_4[2]), float(box_4[3])
    if rule == "official":
        d = max(bw, bh) / out_wh[0] / 2.0
    else:
        d = max(bw / out_wh[0], bh / out_wh[1])
    return (d - 1.0) / 2.0 if d > 1.1 else 0.0


def _region(M_23: np.ndarray, out_wh, margin: int, img_wh) -> tuple[int, int, int, int] | None:
    """Integer image region (x0, y0, x1, y1) the crop samples from, plus a margin, clipped to the image."""
    W, H = out_wh
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [-0.5, H - 0.5], [W - 0.5, H - 0.5]])
    src = apply_affine(invert_affine(M_23), corners)
    x0 = max(int(math.floor(src[:, 0].min())) - margin, 0)
    y0 = max(int(math.floor(src[:, 1].min())) - margin, 0)
    x1 = min(int(math.ceil(src[:, 0].max())) + margin + 1, img_wh[0])
    y1 = min(int(math.ceil(src[:, 1].max())) + margin + 1, img_wh[1])
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def warp_crop(image_hwc: np.ndarray, box_4: np.ndarray, out_wh: tuple[int, int], mask_hw: np.ndarray | None = None,
              rule: str = "scale", rot_rad: float = 0.0, M_23: np.ndarray | None = None,
              ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Crop one box: (image crop (H_in, W_in, C), mask crop (H_in, W_in) or None, M (2, 3) image -> crop).

    The same affine warps image (bilinear) and mask (nearest); outside the image is 0. The
    anti-aliasing blur touches only the region the crop samples from (plus the kernel radius), so
    the result equals blurring the whole frame.
    """
    W, H = out_wh
    M = crop_affine(box_4, out_wh, rot_rad) if M_23 is None else np.asarray(M_23, np.float64)
    sigma = antialias_sigma(box_4, out_wh, rule)
    # "scale" rule: halve with an image pyramid first while the downscale is >= 2 (a 4K frame and a
    # 192 px crop would otherwise need a sigma-5 blur), then blur the remainder as specified
    levels = int(math.floor(math.log2(2 * sigma + 1))) if rule == "scale" and sigma > 0 else 0
    f = 2 ** levels
    if levels:
        sigma = max(0.0, ((2 * sigma + 1) / f - 1) / 2)
        sigma = sigma if sigma > 0.05 else 0.0
    margin = f * (int(math.ceil(4 * sigma)) + 2) + 2 * f + 2
    ih, iw = image_hwc.shape[:2]
    reg = _region(M, out_wh, margin, (iw, ih))
    shape = (H, W) + image_hwc.shape[2:]
    if reg is None:
        crop = np.zeros(shape, image_hwc.dtype)
        mcrop = None if mask_hw is None else np.zeros((H, W), mask_hw.dtype)
        return crop, mcrop, M
    x0, y0, x1, y1 = reg
    Mr = M.copy()
    Mr[:, 2] += M[:, :2] @ np.array([x0, y0], np.float64)  # region px -> crop px
    src = image_hwc[y0:y1, x0:x1]
    Ms = Mr.copy()
    for _ in range(levels):  # pyramid level pixel i sits at level-0 pixel 2^k i
        src = cv2.pyrDown(src)
    if levels:
        Ms[:, :2] *= f
    if sigma > 0:
        src = cv2.GaussianBlur(src, (0, 0), sigmaX=sigma, sigmaY=sigma)
    crop = cv2.warpAffine(src, Ms, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if crop.ndim == 2 and image_hwc.ndim == 3:
        crop = crop[..., None]
    mcrop = None
    if mask_hw is not None:
        m = np.ascontiguousarray(mask_hw[y0:y1, x0:x1]).view(np.uint8) if mask_hw.dtype == bool \
            else mask_hw[y0:y1, x0:x1]
        mcrop = cv2.warpAffine(m, Mr, (W, H), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return crop, mcrop, M


# ---- coordinates -------------------------------------------------------------------------------
def normalised_to_image(n_nl2: np.ndarray, box_n4: np.ndarray) -> np.ndarray:
    """Network xy in [-1, 1] (N, L, 2) -> image px (N, L, 2) for crop boxes (N, 4) cx, cy, bw, bh."""
    n = np.asarray(n_nl2, np.float64)
    b = np.asarray(box_n4, np.float64)[..., None, :]
    return b[..., :2] + n * b[..., 2:] / 2.0


def image_to_normalised(xy_nl2: np.ndarray, box_n4: np.ndarray) -> np.ndarray:
    xy = np.asarray(xy_nl2, np.float64)
    b = np.asarray(box_n4, np.float64)[..., None, :]
    return (xy - b[..., :2]) * 2.0 / b[..., 2:]


def normalised_to_crop(n_l2: np.ndarray, out_wh: tuple[int, int]) -> np.ndarray:
    """Normalised [-1, 1] -> crop px (pixel-centre convention)."""
    wh = np.asarray(out_wh, np.float64)
    return (np.asarray(n_l2, np.float64) + 1.0) / 2.0 * wh - 0.5


def crop_to_normalised(uv_l2: np.ndarray, out_wh: tuple[int, int]) -> np.ndarray:
    wh = np.asarray(out_wh, np.float64)
    return (np.asarray(uv_l2, np.float64) + 0.5) / wh * 2.0 - 1.0


def sigma_to_pixels(log_sigma_nl: np.ndarray, box_n4: np.ndarray) -> np.ndarray:
    """Log sigma in normalised units (N, L) -> sigma in image px per axis (N, L, 2)."""
    s = np.exp(np.asarray(log_sigma_nl, np.float64))[..., None]
    return s * np.asarray(box_n4, np.float64)[..., None, 2:] / 2.0


def pixels_to_log_sigma(sigma_px_nl: np.ndarray, box_n4: np.ndarray, axis: int = 1) -> np.ndarray:
    """Inverse of ``sigma_to_pixels`` for one axis (0 = x, 1 = y)."""
    half = np.asarray(box_n4, np.float64)[..., None, 2 + axis] / 2.0
    return np.log(np.asarray(sigma_px_nl, np.float64) / half)


# ---- network input ------------------------------------------------------------------------------
def normalise_images(crops_bhw3: np.ndarray | torch.Tensor, device: str | torch.device = "cpu") -> torch.Tensor:
    """uint8 RGB crops (B, H, W, 3) -> float (B, 3, H, W) with ImageNet mean/std (x 255)."""
    x = torch.as_tensor(np.asarray(crops_bhw3) if not isinstance(crops_bhw3, torch.Tensor) else crops_bhw3)
    x = x.to(device=device).permute(0, 3, 1, 2).float()
    mean = torch.as_tensor(IMAGENET_MEAN, device=x.device)[None, :, None, None]
    std = torch.as_tensor(IMAGENET_STD, device=x.device)[None, :, None, None]
    return (x - mean) / std


def mask_tensor(masks_bhw: np.ndarray | None, device: str | torch.device = "cpu") -> torch.Tensor | None:
    """Binary crop masks (B, H, W) -> float (B, 1, H, W) in {0, 1}."""
    if masks_bhw is None:
        return None
    return (torch.as_tensor(np.asarray(masks_bhw)) > 0).to(device=device, dtype=torch.float32)[:, None]


# ---- keypoint inputs -----------------------------------------------------------------------------
def crop_keypoints(kp_px_p5: np.ndarray, M_23: np.ndarray, out_wh: tuple[int, int]) -> np.ndarray:
    """Keypoints (P, 5: x, y px, z px-scaled, visibility, presence; NaN x where absent) of an image ->
    the network's input (P, 5) in the crop M_23 cuts: x, y normalised, z in the same units,
    absent points all zero. Training and inference both convert through here."""
    kp = np.asarray(kp_px_p5, np.float64)
    ok = np.isfinite(kp[:, :2]).all(1) & np.isfinite(kp[:, 2])
    out = np.zeros((len(kp), 5), np.float32)
    if ok.any():
        uv = apply_affine(M_23, kp[ok, :2])
        out[ok, :2] = crop_to_normalised(uv, out_wh)
        scale = float(np.sqrt(abs(np.linalg.det(M_23[:, :2]))))  # image px -> crop px
        out[ok, 2] = kp[ok, 2] * scale * 2.0 / out_wh[1]
        out[ok, 3] = np.clip(kp[ok, 3], 0, 1)
        out[ok, 4] = np.clip(kp[ok, 4], 1e-3, 1)  # > 0 marks the point present
    return out
