"""`--backend builtin`: person mask tracks without any weights, for static cameras.

Per camera:

1. Background model: the per-pixel median over frames sampled across the video, then again
   over the samples where that pixel was not foreground (a person standing still for a third
   of the video does not end up in the background). Per-pixel noise from the background samples'
   median absolute deviation. When the camera has a board video (the calibration session, shot
   from the same place), its median is a clean plate: used when it agrees with the capture's
   own background (``plate_background``), so people who never move are still foreground.
2. Foreground in a shadow-robust colour model: each pixel's colour is compared with the
   background as a brightness ratio alpha = <I, B> / <B, B> and a chromatic distortion
   |I - alpha B| (Horprasert-style). A soft shadow darkens the background without changing
   its chromaticity (0.45 < alpha < 1, small distortion): background. Then opening/closing,
   hole filling (for tracking; the masks written keep large holes open: floor seen between two
   people), a rim pass (``refine_rim``: a blurred or chroma-subsampled edge pixel is the
   person's only if it covers at least half of it) and connected components above a minimum area.
3. Tracking: each track's last mask, shifted by its velocity, predicts where it is. A component
   claimed by two or more predictions (people touching or crossing) is split pixel by pixel
   between them by distance to each prediction and each track's colour histogram (colour
   evidence averaged over a small neighbourhood, so the cut follows regions, not single pixels); a track
   that gets (almost) nothing is occluded and coasts on its velocity. A track that alone claims a
   component (its person seen whole) takes no share of another (where it was while hidden). A
   track holding two person-like pieces side by side lets go of the one its prediction covers
   least (two people who came in together, or walked a few pixels apart); if the head count is
   full, two tracks lying one above the other (one person's top and legs) are joined to make room.
   Components no prediction
   claims are matched to recently lost tracks by appearance and position (Hungarian), else
   start new tracks. Tracks lost for more than ``max_lost`` frames end; a person who comes back
   later gets a new track (cross-view matching rejoins it with its person).

Work happens at a reduced resolution (``max_side``) and masks are scaled back to the video's.
Where it struggles (benchmarks/masks_quality.py): people who never move (background), clothes
the colour of the background, and long full occlusions.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from mamma_kit.core import log
from mamma_kit.core.tracks import MaskTracks
from mamma_kit.masks.base import CameraInput, MaskTrackBuilder, track_summary


@dataclass
class BuiltinSettings:
    max_side: int = 960  # working resolution (longest side, px)
    bg_samples: int = 40
    chroma_k: float = 5.0  # chromatic distortion / noise above which a pixel is foreground
    bright_k: float = 6.0  # brightness change / noise above which a brighter pixel is foreground
    shadow_alpha: float = 0.5  # darker than this fraction of the background: not a shadow
    chroma_angle: float = 0.08  # chromatic distortion relative to brightness that marks a new colour
    noise_floor: float = 2.5  # grey levels
    min_area_frac: float = 4e-4  # of the image area: smaller components are noise
    link_frac: float = 0.012  # fragments closer than this fraction of the image height are one instance
    new_track_area_frac: float = 8e-4
    border_area_factor: float = 0.5  # new tracks touching the image border need this share of that area
    claim_frac: float = 0.15  # a prediction claims a component holding this much of it
    occluded_frac: float = 0.12  # a track given less than this fraction of its predicted area is occluded
    colour_weight: float = 1.0
    colour_smooth_frac: float = 0.006  # splitting touching people: colour evidence over this fraction of the height
    max_lost: int = 45  # frames a lost track can be re-identified
    reid_similarity: float = 0.5  # Bhattacharyya coefficient needed to re-identify a lost track
    velocity_smoothing: float = 0.5
    people: int | None = None  # how many people the capture shows (splits blobs of people side by side)
    use_board_plate: bool = True  # background from the camera's board video when it shows the same scene
    plate_max_differ: float = 0.35  # fraction of the image where plate and capture may differ (people)
    edge_coverage: float = 0.5  # rim pixels are the person's if it covers this fraction of them (0: off)
    max_hole_frac: float = 2e-4  # holes larger than this fraction of the image stay open in the masks (0: fill all)


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
    fg = np.stack([_clean(foreground(f, bg, s), f.shape[0]) for f in frames])  # (N, H, W)
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
        import warnings

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


def _radius(h: int) -> int:
    return max(1, int(round(h / 360)))


def _denoise(fg: np.ndarray, h: int) -> np.ndarray:
    """Median filter (drops speckle without eating thin limbs the way an opening does at low
    resolution), a small closing."""
    r = _radius(h)
    m = cv2.medianBlur(fg.astype(np.uint8) * 255, 3 if r < 2 else 5) > 0
    if r >= 2:
        k_open = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r - 1, 2 * r - 1))
        m = cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_OPEN, k_open) > 0
    k_close = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_CLOSE, k_close) > 0


def _clean(fg: np.ndarray, h: int) -> np.ndarray:
    """Denoised foreground with its holes filled."""
    m = _denoise(fg, h)
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


# ---- tracking ------------------------------------------------------------------------
@dataclass
class Track:
    tid: int
    mask: np.ndarray  # last observed mask (bool, working resolution)
    centroid: np.ndarray  # (2,) x, y
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    hist: np.ndarray | None = None
    last_seen: int = 0
    area: float = 0.0

    def predicted(self, frame: int) -> np.ndarray:
        """The last mask shifted by the velocity over the frames since it was seen."""
        d = self.velocity * (frame - self.last_seen)
        if not np.any(np.abs(d) >= 0.5):
            return self.mask
        h, w = self.mask.shape
        M = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
        return cv2.warpAffine(self.mask.astype(np.uint8), M, (w, h), flags=cv2.INTER_NEAREST) > 0


def _centroid(mask: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean(), ys.mean()]) if len(xs) else np.zeros(2)


def _box(mask: np.ndarray) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
    return xs[0], ys[0], xs[-1] + 1, ys[-1] + 1


def _stacked(c: np.ndarray, m: np.ndarray, h: int) -> bool:
    """c lies just above or below m, overlapping it horizontally, and together they are taller
    than wide (one person in two pieces, not two people side by side)."""
    if not m.any():
        return False
    a, b = _box(c), _box(m)
    overlap_x = min(a[2], b[2]) - max(a[0], b[0])
    gap_y = max(a[1], b[1]) - min(a[3], b[3])
    width = max(a[2], b[2]) - min(a[0], b[0])
    height = max(a[3], b[3]) - min(a[1], b[1])
    return overlap_x >= 0.5 * min(a[2] - a[0], b[2] - b[0]) and gap_y <= 0.04 * h and height >= 1.2 * width


def split_component(comp: np.ndarray, preds: list[np.ndarray], hists: list[np.ndarray], cidx: np.ndarray,
                    colour_weight: float, smooth_px: float = 0.0) -> tuple[list[np.ndarray], list[float]]:
    """Share a component's pixels among the predicted masks of the tracks that claim it.

    Each pixel goes to the track maximising -distance to its prediction (in units of a tenth of
    the prediction's size) + colour_weight * log colour likelihood under its histogram, averaged over
    a Gaussian neighbourhood of ``smooth_px`` (one pixel's colour is weak evidence: a shirt's
    shadowed fold can match the other person's trousers, and unsmoothed choices fray the boundary,
    which the next frame's prediction then carries forward). Returns the part per track and its
    mean posterior (a score)."""
    ys, xs = np.nonzero(comp)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    pad = 4
    y0, x0 = max(0, y0 - pad), max(0, x0 - pad)
    y1, x1 = min(comp.shape[0], y1 + pad), min(comp.shape[1], x1 + pad)
    sub = comp[y0:y1, x0:x1]
    py, px = np.nonzero(sub)
    wsum_hw = cv2.GaussianBlur(sub.astype(np.float32), (0, 0), smooth_px) if smooth_px >= 0.5 else None
    scores = []
    for p, h in zip(preds, hists):
        ps = p[y0:y1, x0:x1]
        dist = cv2.distanceTransform((~ps).astype(np.uint8), cv2.DIST_L2, 3)[py, px]
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


class Tracker:
    """Frame-by-frame tracker over foreground components (see module doc)."""

    def __init__(self, shape_hw: tuple[int, int], s: BuiltinSettings):
        self.s = s
        self.h, self.w = shape_hw
        self.tracks: dict[int, Track] = {}
        self.next_id = 0
        self.area_px = self.h * self.w

    def step(self, t: int, fg: np.ndarray, cidx: np.ndarray) -> dict[int, tuple[np.ndarray, float]]:
        s = self.s
        self.next_id_at_frame_start = self.next_id
        comps = components(fg, max(4, int(s.min_area_frac * self.area_px)), int(round(s.link_frac * self.h)))
        live = {k: tr for k, tr in self.tracks.items() if t - tr.last_seen <= s.max_lost}
        self.tracks = live
        recent = [k for k, tr in live.items() if t - tr.last_seen <= 2]  # followed by prediction
        preds = {k: live[k].predicted(t) for k in recent}
        pred_area = {k: max(float(preds[k].sum()), 1.0) for k in recent}
        claim = np.zeros((len(comps), len(recent)))
        for ci, c in enumerate(comps):
            for j, k in enumerate(recent):
                claim[ci, j] = np.count_nonzero(c & preds[k]) / pred_area[k]
        out: dict[int, tuple[np.ndarray, float]] = {}
        pure: set[int] = set()
        unclaimed = []
        whos = []
        for ci, c in enumerate(comps):
            who = [recent[j] for j in np.flatnonzero(claim[ci] >= s.claim_frac)]
            if not who and len(recent) and claim[ci].max() > 0:
                # a small overlap still belongs to the best track if no other component holds it better
                j = int(np.argmax(claim[ci]))
                if claim[:, j].argmax() == ci and claim[ci, j] > 0.02:
                    who = [recent[j]]
            whos.append(who)
        self._leave_ghosts(comps, whos, claim, recent, preds)
        for ci, c in enumerate(comps):
            who = whos[ci]
            if not who:
                unclaimed.append(c)
            elif len(who) == 1:
                k = who[0]
                prev = out.get(k)
                out[k] = ((prev[0] | c) if prev else c, 1.0)
                pure.add(k)
            else:
                parts, conf = split_component(c, [preds[k] for k in who], [live[k].hist for k in who], cidx,
                                              s.colour_weight, s.colour_smooth_frac * self.h)
                for k, m, sc in zip(who, parts, conf):
                    if m.sum() < s.occluded_frac * pred_area[k]:
                        continue  # occluded: coasts on its prediction
                    prev = out.get(k)
                    out[k] = ((prev[0] | m) if prev else m, sc)
        unclaimed += self._part_company(out, preds, pure)
        # fragments of a person already found this frame (clothes the colour of the background cut
        # people in two): stacked above or below its mask -> part of it, not a new person
        rest = []
        for c in sorted(unclaimed, key=lambda c: -int(c.sum())):
            k = next((k for k, (m, _) in out.items() if _stacked(c, m, self.h)), None)
            if k is None:
                rest.append(c)
            else:
                out[k] = (out[k][0] | c, out[k][1])
        unclaimed = rest
        # re-identify lost tracks, else start new ones
        lost = [k for k, tr in live.items() if k not in out and t - tr.last_seen > 0]
        # someone entering through the image border shows a hand first: smaller pieces count there
        big = [c for c in unclaimed
               if c.sum() >= s.new_track_area_frac * self.area_px * (s.border_area_factor if self._at_border(c) else 1.0)]
        if big and lost:
            C = np.full((len(big), len(lost)), 1e6)
            for i, c in enumerate(big):
                hc = histogram(cidx, c)
                cc = _centroid(c)
                for j, k in enumerate(lost):
                    tr = live[k]
                    sim = bhattacharyya(hc, tr.hist) if tr.hist is not None else 0.0
                    gap = t - tr.last_seen
                    reach = np.sqrt(tr.area) * (1.0 + 0.5 * gap) + np.linalg.norm(tr.velocity) * gap
                    dist = np.linalg.norm(cc - (tr.centroid + tr.velocity * gap))
                    if sim >= s.reid_similarity and dist <= reach:
                        C[i, j] = (1 - sim) + 0.2 * dist / max(reach, 1.0)
            r, cc_ = linear_sum_assignment(C)
            taken = set()
            for i, j in zip(r, cc_):
                if C[i, j] < 1e6:
                    out[lost[j]] = (big[i], 1.0)
                    pure.add(lost[j])
                    taken.add(i)
            big = [c for i, c in enumerate(big) if i not in taken]
        for c in big:
            k_new = next((k for k in out if k >= self.next_id_at_frame_start and _stacked(c, out[k][0], self.h)),
                         None)  # a second piece of a person who appeared this frame
            if k_new is not None:
                out[k_new] = (out[k_new][0] | c, 1.0)
                continue
            k = self.next_id
            self.next_id += 1
            self.tracks[k] = Track(k, c, _centroid(c), last_seen=t, hist=histogram(cidx, c), area=float(c.sum()))
            out[k] = (c, 1.0)
            pure.add(k)
        if s.people and len(out) < s.people:
            self._split_blobs(t, out, pure, cidx)
        # update state
        a = self.s.velocity_smoothing
        for k, (m, _) in out.items():
            tr = self.tracks[k]
            c = _centroid(m)
            if t > tr.last_seen and tr.area > 0:
                v = (c - tr.centroid) / (t - tr.last_seen)
                if k in pure:  # a split part's centroid is biased: keep the old velocity
                    tr.velocity = a * tr.velocity + (1 - a) * v
            tr.centroid, tr.mask, tr.last_seen, tr.area = c, m, t, float(m.sum())
            if k in pure:
                hc = histogram(cidx, m)
                tr.hist = hc if tr.hist is None else 0.8 * tr.hist + 0.2 * hc
        return out

    def _leave_ghosts(self, comps: list, whos: list, claim: np.ndarray, recent: list, preds: dict) -> None:
        """A track that alone claims a component (its person, seen whole) does not also take a share
        of a component other people claim, unless the share lies above or below its own component
        (one person in two pieces): that share is where the person was while hidden behind
        another, a ghost the prediction would otherwise carry forward. Edits ``whos`` in place."""
        col = {k: j for j, k in enumerate(recent)}
        home: dict[int, list[int]] = {}
        for ci, who in enumerate(whos):
            if len(who) == 1:
                home.setdefault(who[0], []).append(ci)
        for ci, who in enumerate(whos):
            if len(who) < 2:
                continue
            keep = []
            for k in who:
                j = col[k]
                mine = [h for h in home.get(k, []) if claim[h, j] >= claim[ci, j]]
                if mine and not any(_stacked(comps[ci] & preds[k], comps[h], self.h) for h in mine):
                    continue  # a ghost
                keep.append(k)
            whos[ci] = keep

    def _at_border(self, c: np.ndarray) -> bool:
        return bool(c[0].any() or c[-1].any() or c[:, 0].any() or c[:, -1].any())

    def _part_company(self, out: dict, preds: dict, pure: set) -> list[np.ndarray]:
        """A track whose mask holds two person-like pieces side by side followed two people who
        walked in together, touched when it started, or passed close (a few pixels apart they form
        one linked component): the piece its prediction covers best keeps the track; the others are
        returned as unclaimed (re-identified or new tracks). A person broken up by clothes the colour
        of the background breaks into pieces above one another (``_stacked``) or into a small piece
        (an arm): those stay. With a head count, it is not exceeded."""
        s = self.s
        freed = []
        big = s.new_track_area_frac * self.area_px
        n_people = sum(1 for m, _ in out.values() if m.sum() >= big)  # slivers do not count as people
        for k in list(out):
            if k not in out:  # merged away
                continue
            m_k = out[k][0]
            if k not in pure or m_k.sum() < 2 * big:  # not a part split off a shared component
                continue
            lst = components(m_k, max(1, int(big)))
            if len(lst) < 2:
                continue
            p = preds.get(k)
            lst.sort(key=lambda c: -(np.count_nonzero(c & p) if p is not None else int(c.sum())))
            main = lst[0]
            mx0, my0, mx1, my1 = _box(main)
            for c in lst[1:]:
                x0, y0, x1, y1 = _box(c)
                # not a limb: half as tall, or a third of the area and upright (someone further away)
                person_like = (y1 - y0 >= 0.5 * (my1 - my0)
                               or (c.sum() >= 0.3 * main.sum() and y1 - y0 >= 1.2 * (x1 - x0)))
                apart = min(x1, mx1) - max(x0, mx0) <= 0.5 * min(x1 - x0, mx1 - mx0)  # side by side
                if not (person_like and apart) or _stacked(c, main, self.h):
                    continue
                room = not s.people or n_people + len(freed) < s.people
                if not room and self._merge_stacked(out, pure, big, keep=k):
                    n_people, room = n_people - 1, True
                if room:
                    c = c | self._crumbs_of(c, out[k][0], big)
                    freed.append(c)
                    out[k] = (out[k][0] & ~c, out[k][1])
        return freed

    def _merge_stacked(self, out: dict, pure: set, big: float, keep: int) -> bool:
        """Two tracks this frame whose masks lie one above the other like one person's top and
        bottom (a shirt and trousers of different colours followed as two people after an
        occlusion) become one: the head count needs the place for two people seen side by side.
        The larger keeps its id; ``keep`` is not merged away. True if a pair was merged."""
        ks = [k for k in out if out[k][0].sum() >= big and k != keep]
        best = None
        for i, a in enumerate(ks):
            for b in ks[i + 1:]:
                ma, mb = out[a][0], out[b][0]
                if _stacked(ma, mb, self.h) and (best is None or ma.sum() + mb.sum() > best[2]):
                    best = (a, b, int(ma.sum() + mb.sum()))
        if best is None:
            return False
        a, b, _ = best
        if out[a][0].sum() < out[b][0].sum():
            a, b = b, a
        out[a] = (out[a][0] | out[b][0], min(out[a][1], out[b][1]))
        del out[b]
        self.tracks.pop(b, None)
        pure.discard(b)
        return True

    @staticmethod
    def _crumbs_of(piece: np.ndarray, mask: np.ndarray, min_area: float) -> np.ndarray:
        """The specks of ``mask`` (parts under ``min_area``) nearer ``piece`` than the rest of it:
        they leave with the piece, or they would still tie the two people together."""
        n, lab = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
        small = np.bincount(lab.ravel(), minlength=n) < min_area
        small[0] = False
        crumbs = small[lab] & ~piece
        rest = mask & ~piece & ~crumbs
        if not crumbs.any() or not rest.any():
            return crumbs
        d_piece = cv2.distanceTransform((~piece).astype(np.uint8), cv2.DIST_L2, 3)
        d_rest = cv2.distanceTransform((~rest).astype(np.uint8), cv2.DIST_L2, 3)
        return crumbs & (d_piece < d_rest)

    def _split_blobs(self, t: int, out: dict, pure: set, cidx: np.ndarray) -> None:
        """Fewer tracks than the people the user said are there: a blob holding two people side
        by side (they came in together, or touch from the first frame) becomes two tracks; from
        then on the usual prediction + colour split keeps them apart."""
        for k in sorted(out, key=lambda k: -int(out[k][0].sum())):
            if len(out) >= self.s.people:
                return
            two = split_side_by_side(out[k][0])
            if two is None:
                continue
            tr = self.tracks[k]
            keep = 0 if np.count_nonzero(two[0] & tr.mask) >= np.count_nonzero(two[1] & tr.mask) else 1
            out[k] = (two[keep], 0.5)
            m = two[1 - keep]
            j = self.next_id
            self.next_id += 1
            self.tracks[j] = Track(j, m, _centroid(m), last_seen=t, hist=histogram(cidx, m), area=float(m.sum()))
            out[j] = (m, 0.5)
            pure.add(j)
            tr.hist = histogram(cidx, two[keep])
            tr.area = float(two[keep].sum())


# ---- the backend -------------------------------------------------------------------------
class BuiltinBackend:
    name = "builtin"

    def __init__(self, settings: BuiltinSettings | None = None):
        self.s = settings or BuiltinSettings()

    def _plate(self, cam: CameraInput, capture_bg: Background, prep, size_wh) -> tuple[Background, dict]:
        """The board video's clean plate, or the capture's own background with the reason why not."""
        from mamma_kit.video.reader import VideoReader

        s = self.s
        rd = VideoReader(cam.board_video)
        W, H = size_wh
        bw, bh = rd.size
        if abs(bw / bh - W / H) > 0.01:
            info = {"source": "capture median", "plate": f"board video is {bw}x{bh}, the capture {W}x{H}"}
            log.warn(f"{cam.name}: {info['plate']}: background from the capture itself")
            return capture_bg, info
        n = rd.n_frames
        idx = np.unique(np.round(np.linspace(0, n - 1, min(s.bg_samples, n))).astype(int))
        frames = [prep(img if (bw, bh) == (W, H) else cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA))
                  for _, _, img in rd.read_indices(idx)]
        plate, info = plate_background(frames, capture_bg, s)
        if plate is None:
            log.warn(f"{cam.name}: the board video's scene differs from the capture's on {info['plate_differs']:.0%} "
                     "of the image (camera moved or light changed): background from the capture itself")
            return capture_bg, {"source": "capture median", **info}
        return plate, {"source": "board video", **info}

    def track_camera(self, cam: CameraInput) -> tuple[MaskTracks, dict]:
        from mamma_kit.video.reader import VideoReader

        s = self.s
        rd = VideoReader(cam.video)
        times = rd.timestamps
        W, H = rd.size
        f = min(1.0, s.max_side / max(W, H))
        ws_ = (max(1, int(round(W * f))), max(1, int(round(H * f))))

        def prep(img):
            return img if f == 1.0 else cv2.resize(img, ws_, interpolation=cv2.INTER_AREA)

        n = len(times)
        idx = np.unique(np.round(np.linspace(0, n - 1, min(s.bg_samples, n))).astype(int))
        samples = [prep(img) for _, _, img in rd.read_indices(idx)]
        bg = build_background(samples, s)
        del samples
        bg_info: dict = {"source": "capture median"}
        if cam.board_video is not None and s.use_board_plate:
            bg, bg_info = self._plate(cam, bg, prep, (W, H))
        tracker = Tracker((ws_[1], ws_[0]), s)
        out_tracks = MaskTrackBuilder(cam.name, (W, H), times)
        for t, img in log.track(rd.frames(), f"track {cam.name}", total=n):
            ti = int(np.argmin(np.abs(times - t)))
            small = prep(img)
            dn = _denoise(foreground(small, bg, s), small.shape[0])
            holes = enclosed(dn)
            # tracking sees people with their holes filled (clothes of the background's colour);
            # the masks written keep the large holes open: floor seen between two people or
            # between someone's legs, enclosed by limbs and shadows
            gaps = larger_than(holes, int(s.max_hole_frac * dn.size)) if s.max_hole_frac > 0 else None
            fg = dn | holes
            if s.edge_coverage > 0:
                fg = refine_rim(fg, small, bg, s)
            out = tracker.step(ti, fg, colour_index(small))
            for k, (m, sc) in out.items():
                if gaps is not None:
                    m = m & ~gaps
                if f != 1.0:
                    m = cv2.resize(m.astype(np.uint8) * 255, (W, H), interpolation=cv2.INTER_LINEAR) > 127
                out_tracks.add(ti, k, m, sc)
        mt = out_tracks.build()
        summ = track_summary(mt)
        summ["working_size"] = list(ws_)
        summ["background"] = bg_info
        summ["settings"] = asdict(s)
        return mt, summ


def load_settings(path: Path | None, overrides: dict | None = None) -> BuiltinSettings:
    s = BuiltinSettings()
    for k, v in (overrides or {}).items():
        if hasattr(s, k):
            setattr(s, k, type(getattr(s, k))(v))
    return s
