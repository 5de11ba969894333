"""Training samples from shard crops: the inference crop contract plus augmentation.

``prepare_sample`` turns one shard sample into network input and labels:

- geometry: the crop box of ``crop.expand_box`` around the target's tight box (as at inference),
  then scale (log-uniform), translation and rotation jitter, and sometimes a part crop (a random
  40-75 % slice of the body, so landmarks fall outside the crop with decaying weights);
- photometric / degradation: brightness, contrast, saturation, hue, gamma, white balance, grey,
  Gaussian or motion blur, sensor noise, JPEG artefacts, down-up sampling;
- occluders: random ellipses / polygons / copied patches; landmarks under them become invisible
  and the mask loses them (as SAM would);
- mask corruption like SAM's real errors: dilate / erode, holes, missing limbs (mask removed around a
  cluster of neighbouring landmarks), bleeding into the other person, spurious ovals, blocky edges,
  and no mask at all (an all-zero mask) sometimes.

Every random choice comes from the ``rng`` passed in, so a (seed, step, sample) triple reproduces a
sample exactly (needed for resumable training).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import cv2
import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.landmarks import crop as C


@dataclass(frozen=True)
class AugmentConfig:
    scale: tuple[float, float] = (0.8, 1.3)
    translate: float = 0.08
    p_rotate: float = 0.6
    max_rotate_deg: float = 30.0
    p_part_crop: float = 0.2
    p_photometric: float = 0.9
    p_blur: float = 0.25
    p_noise: float = 0.3
    p_jpeg: float = 0.2
    p_downup: float = 0.15
    p_occluder: float = 0.3
    p_mask_corrupt: float = 0.7
    p_no_mask: float = 0.07
    # keypoint inputs (keypoint-guided models): the keypoint model's own errors come with the data;
    # these add its failures: a point dropped, all points missing, a small extra jitter (box heights)
    p_kp_drop_point: float = 0.05
    p_kp_missing: float = 0.04
    kp_jitter: float = 0.005

    @classmethod
    def from_dict(cls, d: dict) -> "AugmentConfig":
        known = {f.name for f in fields(cls)}
        bad = sorted(set(d) - known)
        if bad:
            raise UserError(f"unknown [augment] keys: {', '.join(bad)}", f"valid keys: {', '.join(sorted(known))}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    @classmethod
    def none(cls) -> "AugmentConfig":
        return cls(scale=(1.0, 1.0), translate=0.0, p_rotate=0.0, p_part_crop=0.0, p_photometric=0.0, p_blur=0.0,
                   p_noise=0.0, p_jpeg=0.0, p_downup=0.0, p_occluder=0.0, p_mask_corrupt=0.0, p_no_mask=0.0,
                   p_kp_drop_point=0.0, p_kp_missing=0.0, kp_jitter=0.0)


def _crop_box(tight_4: np.ndarray, xy_l2: np.ndarray, aug: AugmentConfig, rng: np.random.Generator) -> np.ndarray:
    b = np.asarray(tight_4, np.float64).copy()
    if aug.p_part_crop and rng.random() < aug.p_part_crop:
        h = b[3] - b[1]
        frac = rng.uniform(0.4, 0.75)
        top = b[1] + rng.uniform(0, 1 - frac) * h
        b[1], b[3] = top, top + frac * h
        inside = (xy_l2[:, 1] >= b[1]) & (xy_l2[:, 1] <= b[3])
        if inside.sum() >= 2:  # tighten x to the slice's landmarks
            b[0], b[2] = xy_l2[inside, 0].min(), xy_l2[inside, 0].max()
    box = C.expand_box(b)
    lo, hi = aug.scale
    s = math.exp(rng.uniform(math.log(lo), math.log(hi))) if hi > lo else lo
    box[2:] *= s
    box[:2] += rng.uniform(-1, 1, 2) * aug.translate * box[2:]
    return box


def _photometric(img: np.ndarray, aug: AugmentConfig, rng: np.random.Generator) -> np.ndarray:
    x = img.astype(np.float32)
    if rng.random() < aug.p_photometric:
        x = x * rng.uniform(0.6, 1.4) + rng.uniform(-40, 40)  # contrast, brightness
        x = x * rng.uniform(0.85, 1.15, 3)[None, None]  # white balance
        grey = x.mean(2, keepdims=True)
        x = grey + (x - grey) * (0.0 if rng.random() < 0.05 else rng.uniform(0.4, 1.5))  # saturation
        x = np.clip(x, 0, 255)
        if rng.random() < 0.3:  # hue
            hsv = cv2.cvtColor(x.astype(np.uint8), cv2.COLOR_RGB2HSV)
            hsv[..., 0] = ((hsv[..., 0].astype(np.int32) + int(rng.integers(-12, 13))) % 180).astype(np.uint8)
            x = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB).astype(np.float32)
        x = 255.0 * (x / 255.0) ** rng.uniform(0.7, 1.5)  # gamma
    if rng.random() < aug.p_blur:
        if rng.random() < 0.5:
            x = cv2.GaussianBlur(x, (0, 0), rng.uniform(0.5, 2.0))
        else:
            k = int(rng.integers(3, 10))
            kern = np.zeros((k, k), np.float32)
            kern[k // 2] = 1.0 / k
            rot = cv2.getRotationMatrix2D(((k - 1) / 2, (k - 1) / 2), rng.uniform(0, 180), 1.0)
            kern = cv2.warpAffine(kern, rot, (k, k))
            x = cv2.filter2D(x, -1, kern / max(kern.sum(), 1e-6))
    if rng.random() < aug.p_downup:
        h, w = x.shape[:2]
        f = rng.uniform(0.3, 0.7)
        small = cv2.resize(x, (max(2, int(w * f)), max(2, int(h * f))), interpolation=cv2.INTER_AREA)
        x = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    if rng.random() < aug.p_noise:
        x = x + rng.normal(0, rng.uniform(2, 12), x.shape).astype(np.float32)
    x = np.clip(x, 0, 255).astype(np.uint8)
    if rng.random() < aug.p_jpeg:
        ok, enc = cv2.imencode(".jpg", x, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(15, 70))])
        if ok:
            x = cv2.imdecode(enc, cv2.IMREAD_UNCHANGED).reshape(x.shape)
    return x


def _random_shape(shape_hw, rng: np.random.Generator, centre=None, size: float = 0.2) -> np.ndarray:
    """A filled random ellipse or polygon (uint8 0/1) about ``centre`` (default random)."""
    h, w = shape_hw
    m = np.zeros((h, w), np.uint8)
    c = np.array([rng.uniform(0, w), rng.uniform(0, h)]) if centre is None else np.asarray(centre, float)
    r = size * min(h, w) * rng.uniform(0.4, 1.0)
    if rng.random() < 0.5:
        axes = (max(1, int(r)), max(1, int(r * rng.uniform(0.3, 1.0))))
        cv2.ellipse(m, (int(c[0]), int(c[1])), axes, rng.uniform(0, 180), 0, 360, 1, -1)
    else:
        k = int(rng.integers(3, 7))
        ang = np.sort(rng.uniform(0, 2 * np.pi, k))
        rad = r * rng.uniform(0.5, 1.0, k)
        pts = np.stack([c[0] + rad * np.cos(ang), c[1] + rad * np.sin(ang)], 1).astype(np.int32)
        cv2.fillPoly(m, [pts], 1)
    return m


def _occlude(img, vis, uv_l2, mask, rng: np.random.Generator, person_uv: np.ndarray):
    h, w = img.shape[:2]
    centre = person_uv[rng.integers(len(person_uv))] if len(person_uv) else None
    occ = _random_shape((h, w), rng, centre, size=rng.uniform(0.1, 0.35)).astype(bool)
    if rng.random() < 0.5:  # a patch copied from elsewhere (texture) or a flat colour
        dy, dx = int(rng.integers(-h // 2, h // 2 + 1)), int(rng.integers(-w // 2, w // 2 + 1))
        src = np.roll(img, (dy, dx), (0, 1))
        img = np.where(occ[..., None], src, img)
    else:
        img = np.where(occ[..., None], rng.integers(0, 256, 3).astype(np.uint8)[None, None], img)
    ui = np.clip(np.round(uv_l2).astype(np.int64), [0, 0], [w - 1, h - 1])
    inside = (uv_l2[:, 0] >= -0.5) & (uv_l2[:, 0] < w - 0.5) & (uv_l2[:, 1] >= -0.5) & (uv_l2[:, 1] < h - 0.5)
    covered = inside & occ[ui[:, 1], ui[:, 0]]
    vis = np.where(covered, 0, vis).astype(vis.dtype)
    mask = np.where(occ, 0, mask).astype(mask.dtype)
    return img, vis, mask


def corrupt_mask(mask: np.ndarray, others: np.ndarray, uv_l2: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """SAM-like errors on a crop mask (uint8 0/1); ``others`` = other people's pixels (bool)."""
    h, w = mask.shape
    m = mask.copy()
    unit = max(1, min(h, w) // 48)
    if rng.random() < 0.5:  # dilate / erode
        k = int(rng.integers(1, 3 * unit + 1)) * 2 + 1
        ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
        m = cv2.dilate(m, ker) if rng.random() < 0.5 else cv2.erode(m, ker)
    inside = (uv_l2[:, 0] >= 0) & (uv_l2[:, 0] < w) & (uv_l2[:, 1] >= 0) & (uv_l2[:, 1] < h)
    pts = uv_l2[inside]
    if len(pts) and rng.random() < 0.3:  # missing limb: drop the mask around a cluster of landmarks
        seed = pts[rng.integers(len(pts))]
        d = np.linalg.norm(pts - seed, axis=1)
        take = pts[np.argsort(d)[: max(1, int(len(pts) * rng.uniform(0.05, 0.2)))]]
        dots = np.zeros((h, w), np.uint8)
        ij = np.clip(np.round(take).astype(np.int64), 0, [w - 1, h - 1])
        dots[ij[:, 1], ij[:, 0]] = 1
        k = int(rng.integers(2, 5)) * unit * 2 + 1
        m[cv2.dilate(dots, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0] = 0
    if rng.random() < 0.3:  # holes
        for _ in range(int(rng.integers(1, 4))):
            c = pts[rng.integers(len(pts))] if len(pts) else None
            m[_random_shape((h, w), rng, c, size=0.08).astype(bool)] = 0
    if others.any() and rng.random() < 0.35:  # bleeding into the other person
        ys, xs = np.nonzero(others)
        i = rng.integers(len(xs))
        blob = _random_shape((h, w), rng, (xs[i], ys[i]), size=rng.uniform(0.1, 0.4)).astype(bool)
        m[blob & others] = 1
    if rng.random() < 0.15:  # spurious ovals
        m[_random_shape((h, w), rng, None, size=0.1).astype(bool)] = 1
    if rng.random() < 0.2:  # blocky low-resolution edges
        f = rng.uniform(0.15, 0.5)
        small = cv2.resize(m, (max(2, int(w * f)), max(2, int(h * f))), interpolation=cv2.INTER_NEAREST)
        m = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)
    return m


def _augment_keypoints(kp_p5: np.ndarray, box_h_n: float, aug: AugmentConfig, rng: np.random.Generator) -> np.ndarray:
    kp = kp_p5.copy()
    if aug.p_kp_missing and rng.random() < aug.p_kp_missing:
        return np.zeros_like(kp)
    present = kp[:, 4] > 0
    if aug.kp_jitter:
        kp[present, :2] += rng.normal(0, aug.kp_jitter * box_h_n, (int(present.sum()), 2))
    if aug.p_kp_drop_point:
        kp[present & (rng.random(len(kp)) < aug.p_kp_drop_point)] = 0
    return kp


def prepare_sample(sample: dict, out_wh: tuple[int, int], rule: str, aug: AugmentConfig | None,
                   rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One shard sample -> image (H, W, 3) uint8, mask (H, W) uint8, xy_n (L, 2) float32 normalised,
    visibility / contact / floor_contact (L,) float32, box_h (float: the tight box height in crop px);
    with the others' mask ``others`` (H, W) uint8, and ``keypoints`` (P, 5) where the shard has them."""
    aug = aug or AugmentConfig.none()
    xy = np.asarray(sample["xy"], np.float64)
    # the inference contract boxes the mask (min/max pixel indices); the shard's box is the fallback
    tight = C.mask_box(sample["instance"] == 1)
    if tight is None:
        tight = C.tight_box_from_track_box(np.asarray(sample["box"], np.float64))
    box = _crop_box(tight, xy, aug, rng)
    rot = math.radians(rng.uniform(-aug.max_rotate_deg, aug.max_rotate_deg)) \
        if aug.p_rotate and rng.random() < aug.p_rotate else 0.0
    img, inst, M = C.warp_crop(sample["images"], box, out_wh, sample["instance"], rule=rule, rot_rad=rot)
    uv = C.apply_affine(M, xy)
    vis = np.asarray(sample["visibility"], np.float32).copy()
    mask = (inst == 1).astype(np.uint8)
    others = inst >= 2
    img = _photometric(img, aug, rng)
    if aug.p_occluder and rng.random() < aug.p_occluder:
        img, vis, mask = _occlude(img, vis, uv, mask, rng, uv[vis > 0.5])
    if aug.p_mask_corrupt and rng.random() < aug.p_mask_corrupt:
        mask = corrupt_mask(mask, others, uv, rng)
    if aug.p_no_mask and rng.random() < aug.p_no_mask:
        mask = np.zeros_like(mask)
    scale_y = float(np.hypot(M[1, 0], M[1, 1]))
    extra = {"others": others.astype(np.uint8)}
    if "keypoints" in sample:
        kp = C.crop_keypoints(sample["keypoints"], M, out_wh)
        extra["keypoints"] = _augment_keypoints(kp, (tight[3] - tight[1]) * scale_y * 2.0 / out_wh[1], aug, rng)
    return {
        **extra, "image": img, "mask": mask,
        "xy_n": C.crop_to_normalised(uv, out_wh).astype(np.float32),
        "visibility": vis, "contact": np.asarray(sample["contact"], np.float32),
        "floor_contact": np.asarray(sample["floor_contact"], np.float32),
        "box_h": np.float32((tight[3] - tight[1]) * scale_y),
    }


def collate(samples: list[dict]) -> dict[str, np.ndarray]:
    return {k: np.stack([s[k] for s in samples]) for k in samples[0]}
