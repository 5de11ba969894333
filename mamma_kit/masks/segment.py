"""The builtin backend's pixel work, one frame at a time: colour histograms, the background
model (median + noise, or the board video's clean plate), the shadow-robust foreground test,
denoising and hole filling, the rim pass, connected components, and the two ways a blob is shared
between people (``split_component`` by prediction and colour, ``split_side_by_side`` by its column
profile). See masks/builtin.py's docstring for how the steps fit together.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from mamma_kit.masks.builtin_settings import BuiltinSettings

# ---- colour --------------------------------------------------------------------------
HIST_BINS = (12, 4, 4)  # hue, saturation, value


def colour_index(rgb_hw3: np.ndarray) -> np.ndarray:
    hsv = cv2.cvtColor(rgb_hw3, cv2.COLOR_RGB2HSV)
    h = (hsv[..., 0].astype(np.int32) * HIST_BINS[0]) // 180
    s = (hsv[..., 1].astype(np.int32) * HIST_BINS[1]) // 256
    v = (hsv[..., 2].astype(np.int32) * HIST_BINS[2]) // 256
    return (h * HIST_BINS[1] + s) * HIST_BINS[2] + v


def histogram(idx_hw: np.ndarray, mask_hw: np.ndarray) -> np.ndarray:
    n = int(np.prod(HIST_BINS))
    h = np.bincount(idx_hw[mask_hw], minlength=n).astype(np.float64) + 0.5
    return h / h.sum()


def bhattacharyya(p: np.ndarray, q: np.ndarray) -> float:
    return float(np.sqrt(p * q).sum())


# ---- background ----------------------------------------------------------------------
@dataclass
class Background:
    mean_hw3: np.ndarray  # float32
    noise_hw: np.ndarray  # float32 grey levels


def foreground(img_hw3: np.ndarray, bg: Background, s: BuiltinSettings) -> np.ndarray:
    """Raw foreground (bool (H, W)) by brightness ratio and chromatic distortion."""
    I = img_hw3.astype(np.float32)
    B = bg.mean_hw3
    bb = (B * B).sum(-1) + 1.0
    alpha = (I * B).sum(-1) / bb
    cd = np.linalg.norm(I - alpha[..., None] * B, axis=-1)
    bnorm = np.sqrt(bb)
    sig = bg.noise_hw
    # chromatic change: large against the noise, or moderate and a clear change of hue direction
    chroma = (cd > s.chroma_k * sig) | ((cd > 3.0 * sig) & (cd > s.chroma_angle * np.linalg.norm(I, axis=-1)))
    brighter = (alpha - 1.0) * bnorm > s.bright_k * sig
    darker = (1.0 - alpha) * bnorm > s.bright_k * sig
    # a darker pixel with background chromaticity is a shadow unless it is far too dark
    too_dark = darker & (alpha < s.shadow_alpha)
    return chroma | brighter | too_dark


def build_background(frames: list[np.ndarray], s: BuiltinSettings) -> Background:
    stack = np.stack(frames).astype(np.float32)  # (N, H, W, 3)
    med = np.median(stack, 0)
    noise0 = np.full(med.shape[:2], s.noise_floor * 2, np.float32)
    bg = Background(med, noise0)
    fg = np.stack([clean(foreground(f, bg, s), f.shape[0]) for f in frames])  # (N, H, W)
    dev = np.abs(stack - med).mean(-1)  # (N, H, W)
    keep = ~fg
    enough = keep.sum(0) >= max(3, len(frames) // 4)
    if enough.any():
        masked = np.where(keep[..., None], stack, np.nan)
        med2 = np.nanmedian(masked[:, enough], 0)  # (M, 3)
        med = med.copy()
        med[enough] = med2
        dev = np.abs(stack - med).mean(-1)
    dev = np.where(keep, dev, np.nan)
    with np.errstate(all="ignore"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mad = np.nanmedian(dev, 0)
    noise = np.where(np.isfinite(mad), 1.4826 * mad * 1.25, s.noise_floor * 2)  # mean|.| of 3 channels -> sigma
    noise = cv2.GaussianBlur(noise.astype(np.float32), (0, 0), 2.0)
    # pixels people cover in most samples look noisy: cap at 3x the image's typical noise
    noise = np.minimum(noise, 3.0 * max(float(np.median(noise)), s.noise_floor))
    return Background(med.astype(np.float32), np.maximum(noise, s.noise_floor).astype(np.float32))


def plate_background(frames: list[np.ndarray], capture_bg: Background, s: BuiltinSettings
                     ) -> tuple[Background | None, dict]:
    """The background from frames of the camera's board video (a clean plate), if it shows
    the capture's scene: calibration already assumes the camera did not move between the two,
    and the board and its holder move about, so the median leaves the empty scene - also where
    the people of the capture never moved. Checked against the capture's own median (which is
    right wherever nobody stood for long): a per-channel gain absorbs a change of light; if the
    two still differ on more than ``plate_max_differ`` of the image, the plate is not used."""
    plate = build_background(frames, s)
    A, B = plate.mean_hw3, capture_bg.mean_hw3
    sig = np.maximum(np.maximum(plate.noise_hw, capture_bg.noise_hw), s.noise_floor)
    close = np.abs(A - B).max(-1) < 6.0 * sig
    gain = np.ones(3, np.float32)
    if close.mean() > 0.05:
        gain = np.median(B[close] / np.maximum(A[close], 1.0), 0).astype(np.float32)
        A = A * gain
        close = np.abs(A - B).max(-1) < 6.0 * sig
    differ = 1.0 - float(close.mean())
    info = {"plate_differs": round(differ, 3), "plate_gain": [round(float(g), 3) for g in gain]}
    if differ > s.plate_max_differ:
        return None, info
    return Background(A.astype(np.float32), np.maximum(plate.noise_hw, s.noise_floor).astype(np.float32)), info


# ---- cleaning and components ----------------------------------------------------------
def _radius(h: int) -> int:
    return max(1, int(round(h / 360)))


def denoise(fg: np.ndarray, h: int) -> np.ndarray:
    """Median filter (drops speckle without eating thin limbs the way an opening does at low
    resolution), a small closing."""
    r = _radius(h)
    m = cv2.medianBlur(fg.astype(np.uint8) * 255, 3 if r < 2 else 5) > 0
    if r >= 2:
        k_open = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r - 1, 2 * r - 1))
        m = cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_OPEN, k_open) > 0
    k_close = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_CLOSE, k_close) > 0


def clean(fg: np.ndarray, h: int) -> np.ndarray:
    """Denoised foreground with its holes filled."""
    m = denoise(fg, h)
    return m | enclosed(m)


def refine_rim(fg_hw: np.ndarray, img_hw3: np.ndarray, bg: Background, s: BuiltinSettings) -> np.ndarray:
    """Decide the pixels on a mask's rim by how much of each the person covers.

    Compressed video blurs a person's edge over a few pixels (and 4:2:0 chroma shares one colour
    between two pixels), so the colour test marks a rim a pixel or two wider than the person. A rim
    pixel's colour is modelled as a blend I = a F + (1 - a) B of the person's colour F (around the nearest
    pixel deeper inside the mask) and the background's B; it belongs to the person if a >= ``edge_coverage``.
    Pixels just outside the mask are tested the same way. Where the person's colour is too close
    to the background's for a to be measured, the colour test's answer stands.
    """
    m = fg_hw.astype(np.uint8)
    k3 = np.ones((3, 3), np.uint8)
    inner = cv2.erode(m, k3, iterations=2)
    if not inner.any():
        return fg_hw
    band = (cv2.dilate(m, k3) > 0) & (inner == 0)
    dist, lab = cv2.distanceTransformWithLabels(1 - inner, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    zy, zx = np.nonzero(inner)
    pos_l2 = np.zeros((int(lab.max()) + 1, 2), np.int64)
    pos_l2[lab[zy, zx]] = np.stack([zy, zx], 1)
    by, bx = np.nonzero(band & (dist <= 4.5))
    src = pos_l2[lab[by, bx]]
    # the person's colour: mean of the interior over 5x5 (normalised convolution: less noise)
    w_hw = cv2.blur(inner.astype(np.float32), (5, 5))
    sum_hw3 = cv2.blur(img_hw3.astype(np.float32) * inner[..., None], (5, 5))
    I = img_hw3[by, bx].astype(np.float32)
    F = sum_hw3[src[:, 0], src[:, 1]] / np.maximum(w_hw[src[:, 0], src[:, 1]], 1e-6)[:, None]
    B = bg.mean_hw3[by, bx]
    d = F - B
    dd = (d * d).sum(-1)
    sig = bg.noise_hw[by, bx]
    measurable = dd > 3 * (4.0 * sig) ** 2  # |F - B| above 4 noise sigmas in each of 3 channels
    a = ((I - B) * d).sum(-1) / np.maximum(dd, 1e-6)
    out = fg_hw.copy()
    out[by[measurable], bx[measurable]] = a[measurable] >= s.edge_coverage
    return out


def enclosed(mask: np.ndarray) -> np.ndarray:
    """Background the image border cannot reach: the holes of the mask."""
    h, w = mask.shape
    pad = np.zeros((h + 2, w + 2), np.uint8)
    pad[1:-1, 1:-1] = mask
    ff = np.zeros((h + 4, w + 4), np.uint8)
    cv2.floodFill(pad, ff, (0, 0), 1)
    return (1 - pad)[1:-1, 1:-1].astype(bool)


def larger_than(mask: np.ndarray, area: int) -> np.ndarray:
    """The 4-connected parts of the mask with more than ``area`` pixels."""
    n, lab, st, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=4)
    large = st[:, cv2.CC_STAT_AREA] > area
    large[0] = False
    return large[lab]


def components(mask: np.ndarray, min_area: int, link_px: int = 0) -> list[np.ndarray]:
    """Connected components of the mask with at least ``min_area`` pixels. Fragments closer than
    ``link_px`` (a person broken up by clothes the colour of the background) are one component."""
    lab_src = mask.astype(np.uint8)
    if link_px > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * link_px + 1, 2 * link_px + 1))
        lab_src = cv2.dilate(lab_src, k)
    n, lab = cv2.connectedComponents(lab_src, connectivity=8)
    if n <= 1:
        return []
    lab = np.where(mask, lab, 0)
    area = np.bincount(lab.ravel(), minlength=n)
    return [lab == i for i in range(1, n) if area[i] >= min_area]


# ---- one blob, several people ----------------------------------------------------------
def body_axes(preds: list[np.ndarray], min_px: int = 20) -> np.ndarray | None:
    """(K, 2) x of each predicted mask's vertical axis (the median column of its lower 45 %: hips
    and legs, which clothes tell apart more often than shirts) and that part's width (10-90 %
    of its columns); None if a prediction has fewer than ``min_px`` pixels."""
    out = []
    for p in preds:
        yy, xx = np.nonzero(p)
        if len(yy) < min_px:
            return None
        low = xx[yy >= np.percentile(yy, 55)]
        out.append((np.median(low), np.percentile(low, 90) - np.percentile(low, 10)))
    return np.array(out, np.float64)


def split_component(comp: np.ndarray, preds: list[np.ndarray], hists: list[np.ndarray], cidx: np.ndarray,
                    colour_weight: float, smooth_px: float = 0.0, axis_weight: float = 0.0,
                    axis_separation: float = 1.0) -> tuple[list[np.ndarray], list[float]]:
    """Share a component's pixels among the predicted masks of the tracks that claim it.

    Each pixel goes to the track maximising -distance to its prediction (in units of a tenth of
    the prediction's size) + colour_weight * log colour likelihood under its histogram, averaged over
    a Gaussian neighbourhood of ``smooth_px`` (one pixel's colour is weak evidence: a shirt's
    shadowed fold can match the other person's trousers, and unsmoothed choices fray the boundary,
    which the next frame's prediction then carries forward). With ``axis_weight`` > 0 and the
    claimants standing apart (their ``body_axes`` at least ``axis_separation`` widths apart), each
    pixel's horizontal distance to a track's axis counts too, in the same units as the distance
    to its prediction: two people whose shirts match (the colour cannot tell) keep their upper
    bodies above their own legs, where the prediction alone let one drift onto the other. Returns
    the part per track and its mean posterior (a score)."""
    ys, xs = np.nonzero(comp)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    pad = 4
    y0, x0 = max(0, y0 - pad), max(0, x0 - pad)
    y1, x1 = min(comp.shape[0], y1 + pad), min(comp.shape[1], x1 + pad)
    sub = comp[y0:y1, x0:x1]
    py, px = np.nonzero(sub)
    wsum_hw = cv2.GaussianBlur(sub.astype(np.float32), (0, 0), smooth_px) if smooth_px >= 0.5 else None
    axes = body_axes(preds) if axis_weight > 0 and len(preds) > 1 else None
    if axes is not None:
        gap = min(abs(axes[i, 0] - axes[j, 0]) / max(0.5 * (axes[i, 1] + axes[j, 1]), 1.0)
                  for i in range(len(axes)) for j in range(i + 1, len(axes)))
        if gap < axis_separation:  # one behind the other: the axes say nothing about who is who
            axes = None
    scores = []
    for k, (p, h) in enumerate(zip(preds, hists)):
        ps = p[y0:y1, x0:x1]
        dist = cv2.distanceTransform((~ps).astype(np.uint8), cv2.DIST_L2, 3)[py, px]
        if axes is not None:
            dist = dist + axis_weight * np.abs(x0 + px - axes[k, 0])
        size = max(np.sqrt(max(p.sum(), 1.0)), 4.0)
        if h is not None:
            col_hw = np.log(h[cidx[y0:y1, x0:x1]]).astype(np.float32)
            if smooth_px >= 0.5:  # colour evidence of the neighbourhood, over the component's pixels only
                col_hw = cv2.GaussianBlur(col_hw * sub, (0, 0), smooth_px) / np.maximum(wsum_hw, 1e-6)
            col = col_hw[py, px]
        else:
            col = 0.0
        scores.append(-dist / (0.1 * size) + colour_weight * col)
    S = np.stack(scores)  # (K, n)
    lab = np.argmax(S, 0)
    post = np.exp(S - S.max(0))
    post = post / post.sum(0)
    parts, conf = [], []
    for k in range(len(preds)):
        m = np.zeros_like(comp)
        sel = lab == k
        m[y0 + py[sel], x0 + px[sel]] = True
        parts.append(m)
        conf.append(float(post[k, sel].mean()) if sel.any() else 0.0)
    return parts, conf


def split_side_by_side(mask: np.ndarray, min_height: float = 0.6, valley: float = 0.35
                       ) -> tuple[np.ndarray, np.ndarray] | None:
    """Two people side by side in one blob (holding hands, arm in arm) -> their two masks, cut
    at the deepest valley of the column profile (foreground pixels per column) in the middle
    60 % of the blob; None unless both sides are person-like: at least ``min_height`` of the
    blob tall, a quarter of its area, and the valley below ``valley`` x the lower side's peak.
    A single person with arms out has no such valley (one side would be an arm, not tall)."""
    ys, xs = np.nonzero(mask)
    if len(xs) < 50:
        return None
    x0, x1, y0, y1 = xs.min(), xs.max() + 1, ys.min(), ys.max() + 1
    prof = np.bincount(xs - x0, minlength=x1 - x0).astype(np.float64)
    prof = np.convolve(prof, np.ones(3) / 3, mode="same")
    w = x1 - x0
    lo, hi = int(0.2 * w), int(0.8 * w)
    if hi - lo < 3:
        return None
    cut = lo + int(np.argmin(prof[lo:hi]))
    left, right = xs - x0 < cut, xs - x0 >= cut
    H, area = y1 - y0, len(xs)
    for side in (left, right):
        if side.sum() < 0.25 * area or np.ptp(ys[side]) + 1 < min_height * H:
            return None
    if prof[cut] > valley * min(prof[:cut].max(), prof[cut:].max()):
        return None
    a = np.zeros_like(mask)
    b = np.zeros_like(mask)
    a[ys[left], xs[left]] = True
    b[ys[right], xs[right]] = True
    return a, b

