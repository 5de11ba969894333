"""The MammaNet crop contract (crop.py): box, warp, normalised coordinates, sigma per axis."""

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mamma_kit.landmarks import crop as C

OFFICIAL_WH = (384, 512)
EMBEDDED_WH = (144, 192)


def test_expand_box_official_numbers():
    # a 100 x 300 person: x1.2 -> 120 x 360, grown to 3:4 -> 270 x 360
    b = C.expand_box(np.array([50.0, 20.0, 150.0, 320.0]))
    assert np.allclose(b, [100.0, 170.0, 270.0, 360.0])
    # a wide box grows in height, never shrinks in width
    b = C.expand_box(np.array([0.0, 0.0, 400.0, 100.0]))
    assert np.allclose(b, [200.0, 50.0, 480.0, 640.0])


@settings(max_examples=80, deadline=None)
@given(w=st.floats(2, 3000), h=st.floats(2, 3000), x=st.floats(-50, 4000), y=st.floats(-50, 2200))
def test_expand_box_aspect_and_never_shrinks(w, h, x, y):
    b = C.expand_box(np.array([x, y, x + w, y + h]))
    assert b[2] / b[3] == pytest.approx(0.75, rel=1e-9)
    assert b[2] >= 1.2 * w - 1e-9 and b[3] >= 1.2 * h - 1e-9
    assert b[2] == pytest.approx(1.2 * w) or b[3] == pytest.approx(1.2 * h)
    assert np.allclose(b[:2], [x + w / 2, y + h / 2])


@settings(max_examples=150, deadline=None)
@given(cx=st.floats(-100, 4000), cy=st.floats(-100, 2300), bh=st.floats(8, 3000),
       u=st.floats(-1.5, 1.5), v=st.floats(-1.5, 1.5))
def test_normalised_roundtrip_within_0_01_px(cx, cy, bh, u, v):
    box = np.array([[cx, cy, 0.75 * bh, bh]])
    p = np.array([[[cx + u * 0.75 * bh / 2, cy + v * bh / 2]]])
    n = C.image_to_normalised(p, box)
    assert np.allclose(n, [[[u, v]]], atol=1e-9)  # documented: n = (x - cx) / (bw / 2)
    assert np.abs(C.normalised_to_image(n, box) - p).max() < 0.01
    for wh in (OFFICIAL_WH, EMBEDDED_WH):  # crop px <-> normalised
        uv = C.normalised_to_crop(n[0], wh)
        assert np.allclose(C.crop_to_normalised(uv, wh), n[0], atol=1e-12)
        # and the affine used for warping agrees with the normalised map
        M = C.crop_affine(box[0], wh)
        assert np.abs(C.apply_affine(M, p[0]) - uv).max() < 1e-6


def test_documented_edges_official():
    box = np.array([200.0, 300.0, 384.0, 512.0])  # 1:1 scale
    M = C.crop_affine(box, OFFICIAL_WH)
    # the box's left/top edge is the crop's continuous edge -0.5 and n = -1
    assert np.allclose(C.apply_affine(M, [[200 - 192, 300 - 256]]), [[-0.5, -0.5]])
    assert np.allclose(C.crop_to_normalised([[-0.5, -0.5], [383.5, 511.5]], OFFICIAL_WH), [[-1, -1], [1, 1]])
    # crop pixel (0, 0) is centred at n = -1 + 1/384, -1 + 1/512
    assert np.allclose(C.crop_to_normalised([[0, 0]], OFFICIAL_WH), [[-1 + 1 / 384, -1 + 1 / 512]])


def _blob_image(w, h, x0, y0, s):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return (np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * s * s)) * 200.0).astype(np.float32)


def _centroid(img):
    img = img.astype(np.float64)
    img = np.where(img > 0.02 * img.max(), img, 0)
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    return np.array([(img * xx).sum(), (img * yy).sum()]) / img.sum()


CASES = [  # (image w, h, tight box, point in the box as a fraction, rule)
    (640, 480, (300, 100, 360, 400), (0.3, 0.6), "scale"),        # tall person, ~1.6x downscale
    (640, 480, (0, 200, 260, 479), (0.2, 0.7), "scale"),          # touching the left/bottom borders
    (1920, 1080, (1500, 50, 1919, 1079), (0.8, 0.1), "scale"),    # big, near the right edge: pyramid path
    (1920, 1080, (700, 100, 1100, 1060), (0.5, 0.5), "official"),  # official rule, blur
    (320, 240, (100, 60, 130, 110), (0.4, 0.3), "official"),      # small person: upscaling
    (320, 240, (200, 20, 300, 60), (0.9, 0.5), "scale"),          # wide box
]


@pytest.mark.parametrize("w,h,tight,frac,rule", CASES)
def test_warp_puts_a_point_at_its_normalised_coordinates(w, h, tight, frac, rule):
    wh = OFFICIAL_WH if rule == "official" else EMBEDDED_WH
    box = C.expand_box(np.array(tight, float))
    x1, y1, x2, y2 = tight
    p = np.array([x1 + frac[0] * (x2 - x1) + 0.37, y1 + frac[1] * (y2 - y1) - 0.21])
    scale = box[3] / wh[1]  # image px per crop px
    s = 3.0 * max(scale, 1.0)  # a blob of >= 3 crop px, kept inside the image
    p = np.clip(p, 5 * s, [w - 1 - 5 * s, h - 1 - 5 * s])
    img = _blob_image(w, h, p[0], p[1], s)
    crop, _, M = C.warp_crop(img, box, wh, rule=rule)
    n_expected = C.image_to_normalised(p[None, None], box[None])[0, 0]
    uv = _centroid(crop)
    n_found = C.crop_to_normalised(uv, wh)
    # the blob lands where the documented coordinates say, to a few hundredths of a crop pixel
    assert np.abs(C.normalised_to_crop(n_expected, wh) - uv).max() < 0.02
    back = C.normalised_to_image(n_found[None, None], box[None])[0, 0]
    assert np.abs(back - p).max() < 0.02 * scale + 1e-3
    # outside the image is 0 (border constant)
    corners = C.apply_affine(C.invert_affine(M), [[0, 0], [wh[0] - 1, 0], [0, wh[1] - 1], [wh[0] - 1, wh[1] - 1]])
    for (cx_, cy_), (u, v) in zip(corners, [(0, 0), (wh[0] - 1, 0), (0, wh[1] - 1), (wh[0] - 1, wh[1] - 1)]):
        if cx_ < -2 or cy_ < -2 or cx_ > w + 1 or cy_ > h + 1:
            assert crop[v, u] == 0


def test_region_blur_equals_full_frame_blur():
    rng = np.random.default_rng(3)
    img = rng.uniform(0, 255, (1080, 1920, 3)).astype(np.float32)
    box = C.expand_box(np.array([800.0, 60.0, 1150.0, 1050.0]))
    sigma = C.antialias_sigma(box, OFFICIAL_WH, "official")
    d = box[3] / 384 / 2  # official: max(box) / 384 / 2
    assert sigma == pytest.approx((d - 1) / 2) and sigma > 0
    crop, _, M = C.warp_crop(img, box, OFFICIAL_WH, rule="official")
    full = cv2.GaussianBlur(img, (0, 0), sigmaX=sigma, sigmaY=sigma)
    ref = cv2.warpAffine(full, M, OFFICIAL_WH, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    assert np.abs(crop - ref).max() < 1e-2


def test_no_blur_when_downscale_is_small():
    box = np.array([100.0, 100.0, 144 * 1.05, 192 * 1.05])
    assert C.antialias_sigma(box, EMBEDDED_WH, "scale") == 0.0
    box = np.array([100.0, 100.0, 144 * 1.2, 192 * 1.2])
    assert C.antialias_sigma(box, EMBEDDED_WH, "scale") == pytest.approx(0.1)


def test_mask_nearest_and_zero_outside():
    h, w = 200, 300
    mask = np.zeros((h, w), bool)
    mask[20:190, 250:300] = True  # touches the right border
    img = np.full((h, w, 3), 90, np.uint8)
    box = C.expand_box(C.mask_box(mask))
    assert np.allclose(C.mask_box(mask), [250, 20, 299, 189])
    crop, mcrop, M = C.warp_crop(img, box, EMBEDDED_WH, mask)
    assert set(np.unique(mcrop)) <= {0, 1}
    # crop pixels whose centre maps right of the image are 0 in image and mask
    src = C.apply_affine(C.invert_affine(M), np.stack(np.meshgrid(np.arange(144), np.arange(192)), -1).reshape(-1, 2))
    outside = (src[:, 0] > w + 0.5).reshape(192, 144)
    assert outside.any() and (crop[outside] == 0).all() and (mcrop[outside] == 0).all()
    inside_mask = ((src[:, 0] > 251) & (src[:, 0] < 298) & (src[:, 1] > 21) & (src[:, 1] < 188)).reshape(192, 144)
    assert (mcrop[inside_mask] == 1).all()


def test_track_box_convention():
    m = np.zeros((50, 60), bool)
    m[10:20, 30:41] = True
    from mamma_kit.core.tracks import MaskTracks

    mt = MaskTracks.from_masks("c", (60, 50), np.array([0.0]), np.array([1]), {(0, 0): m})
    assert np.allclose(C.tight_box_from_track_box(mt.boxes[0, 0]), C.mask_box(m))


@settings(max_examples=60, deadline=None)
@given(bw=st.floats(10, 3000), ls=st.floats(-6, 1), nx=st.floats(-1, 1), ny=st.floats(-1, 1))
def test_sigma_per_axis(bw, ls, nx, ny):
    box = np.array([[123.0, 456.0, bw, bw / 0.75]])
    sig = C.sigma_to_pixels(np.array([[ls]]), box)[0, 0]
    # one normalised unit = half the box: sigma_x = e^s bw / 2, sigma_y = e^s bh / 2
    assert sig[0] == pytest.approx(math.exp(ls) * bw / 2) and sig[1] == pytest.approx(math.exp(ls) * bw / 0.75 / 2)
    # = the image-space displacement of a normalised step of size e^s on each axis
    n = np.array([[[nx, ny]]])
    step = C.normalised_to_image(n + math.exp(ls), box) - C.normalised_to_image(n, box)
    assert np.allclose(step[0, 0], sig, rtol=1e-9)
    assert C.pixels_to_log_sigma(sig[None, None, 1:2][..., 0], box, axis=1)[0, 0] == pytest.approx(ls)
