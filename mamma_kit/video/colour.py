"""HDR phone video to the SDR pictures the detectors were trained on.

Phones record HLG (iPhone's default "HDR video") or PQ, BT.2020 primaries, 10 bits. Read as if
it were SDR, such a frame looks flat and pale, and the board detector, BlazePose and MammaNet see
less contrast than a person watching it on the phone. This converts each frame the way a
broadcast HDR-to-SDR converter does (ITU-R BT.2100 and BT.2408):

1. Y'CbCr -> R'G'B' with the file's own matrix (swscale, 16 bits per channel);
2. the transfer inverted: HLG's inverse OETF then its OOTF (system gamma 1.2 at the nominal
   1000 cd/m2 peak), or PQ's EOTF (absolute cd/m2);
3. HDR reference white (203 cd/m2, BT.2408) -> SDR white, BT.2020 -> BT.709 primaries (linear);
4. highlights above 0.8 of SDR white rolled off smoothly to 1 (a C1 shoulder), colours outside
   BT.709 clipped;
5. BT.1886 encoding (gamma 2.4), 8 bits.

The transfer steps are lookup tables on the 16-bit codes; the per-pixel work is one luminance
power, a 3x3 matrix (cv2.transform) and a table lookup: ~50 ms per 1920x1080 frame here.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

# AVColorTransferCharacteristic values (libavutil/pixfmt.h)
TRC_PQ = 16  # SMPTE ST 2084
TRC_HLG = 18  # ARIB STD-B67
HDR_TRANSFERS = {TRC_PQ: "pq", TRC_HLG: "hlg"}

REFERENCE_WHITE_CD = 203.0  # BT.2408: HDR reference (graphics) white
HLG_PEAK_CD = 1000.0  # the nominal display the OOTF is defined for
HLG_GAMMA = 1.2  # BT.2100 system gamma at 1000 cd/m2
KNEE = 0.8  # of SDR white: below it the picture is left as it is
SDR_GAMMA = 2.4  # BT.1886

# BT.2020 -> BT.709 on linear light (ITU-R BT.2087)
BT2020_TO_709_33 = np.array([[1.6605, -0.5876, -0.0728],
                             [-0.1246, 1.1329, -0.0083],
                             [-0.0182, -0.1006, 1.1187]], np.float32)
BT2020_LUMA_3 = np.array([0.2627, 0.6780, 0.0593], np.float32)

_CODES = 65536  # 16-bit lookup tables
# BT.2100 HLG constants
_HLG_A, _HLG_B = 0.17883277, 0.28466892
_HLG_C = 0.5 - _HLG_A * np.log(4 * _HLG_A)


def transfer_of(color_trc: int | None) -> str:
    """'hlg', 'pq' or 'sdr' for a frame's ``color_trc``."""
    return HDR_TRANSFERS.get(int(color_trc or 0), "sdr")


def hlg_inverse_oetf(e: np.ndarray) -> np.ndarray:
    """HLG signal E' in [0, 1] -> normalised scene light E in [0, 1] (BT.2100 table 5)."""
    e = np.clip(np.asarray(e, np.float64), 0, 1)
    return np.where(e <= 0.5, e * e / 3.0, (np.exp((e - _HLG_C) / _HLG_A) + _HLG_B) / 12.0)


def pq_eotf(e: np.ndarray) -> np.ndarray:
    """PQ signal E' in [0, 1] -> display light in cd/m2 (SMPTE ST 2084)."""
    m1, m2 = 2610 / 16384, 2523 / 4096 * 128
    c1, c2, c3 = 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32
    p = np.clip(np.asarray(e, np.float64), 0, 1) ** (1 / m2)
    return 10000.0 * (np.maximum(p - c1, 0) / (c2 - c3 * p)) ** (1 / m1)


def shoulder(x: np.ndarray, knee: float = KNEE) -> np.ndarray:
    """Relative SDR light: x below ``knee`` unchanged, above it rolled off towards 1 (C1 at the knee)."""
    x = np.asarray(x, np.float64)
    w = 1.0 - knee
    return np.where(x <= knee, x, knee + w * (1.0 - np.exp(-(x - knee) / w)))


@lru_cache(maxsize=None)
def _tables(transfer: str) -> tuple[np.ndarray, np.ndarray, float]:
    """(code16 -> linear light as a fraction of SDR white (float32), sqrt-spaced linear -> 8-bit
    code (uint8), the linear ceiling the second table spans)."""
    codes = np.arange(_CODES) / (_CODES - 1)
    if transfer == "hlg":
        lin = hlg_inverse_oetf(codes)  # scene light; the OOTF (luminance-dependent) is applied per pixel
        ceiling = HLG_PEAK_CD / REFERENCE_WHITE_CD
    else:
        lin = pq_eotf(codes) / REFERENCE_WHITE_CD
        ceiling = 10000.0 / REFERENCE_WHITE_CD
    # the second table's index is sqrt(L / ceiling): fine steps near black, where 8 bits need them
    L = (np.arange(_CODES) / (_CODES - 1)) ** 2 * ceiling
    out = np.round(255.0 * shoulder(L) ** (1.0 / SDR_GAMMA)).astype(np.uint8)
    return lin.astype(np.float32), out, float(ceiling)


def hdr_to_sdr(rgb16_hw3: np.ndarray, transfer: str) -> np.ndarray:
    """An HLG or PQ frame as 16-bit R'G'B' (BT.2020) -> 8-bit BT.709 RGB for an SDR display."""
    import cv2

    to_linear, encode, ceiling = _tables(transfer)
    e_hw3 = to_linear[rgb16_hw3]  # (H, W, 3) float32
    if transfer == "hlg":
        # OOTF: F_D = Y_s^(gamma - 1) E_s (relative to the 1000 cd/m2 peak), then to SDR white units
        y_hw = cv2.transform(e_hw3, BT2020_LUMA_3[None])
        gain = np.power(np.maximum(y_hw, 1e-7), HLG_GAMMA - 1.0, dtype=np.float32)
        gain *= np.float32(HLG_PEAK_CD / REFERENCE_WHITE_CD)
        e_hw3 *= gain[..., None]
    e_hw3 = cv2.transform(e_hw3, BT2020_TO_709_33)
    np.clip(e_hw3, 0.0, ceiling, out=e_hw3)
    idx = np.sqrt(e_hw3 * np.float32(1.0 / ceiling))
    idx *= np.float32(_CODES - 1)
    return encode[idx.astype(np.uint16)]


def sdr_to_hlg(rgb8_hw3: np.ndarray) -> np.ndarray:
    """The inverse, for writing HLG test files: 8-bit BT.709 RGB (BT.1886 display) -> 16-bit HLG
    R'G'B' in BT.2020, SDR white at HDR reference white (the "scene-light" mapping of BT.2408,
    without the shoulder: every SDR level below 1 maps to one HLG level)."""
    lin709 = (np.asarray(rgb8_hw3, np.float32) / 255.0) ** SDR_GAMMA  # relative to SDR white
    lin2020 = lin709 @ np.linalg.inv(BT2020_TO_709_33).T  # BT.709 -> BT.2020 (linear)
    f_d = np.clip(lin2020, 0, None) * (REFERENCE_WHITE_CD / HLG_PEAK_CD)  # display light, 1 = peak
    y = np.maximum(f_d @ BT2020_LUMA_3, 1e-9)
    e_s = f_d * (y ** ((1.0 - HLG_GAMMA) / HLG_GAMMA))[..., None]  # inverse OOTF
    e_s = np.clip(e_s, 0, 1)
    sig = np.where(e_s <= 1 / 12, np.sqrt(3 * e_s), _HLG_A * np.log(np.maximum(12 * e_s - _HLG_B, 1e-12)) + _HLG_C)
    return np.round(np.clip(sig, 0, 1) * 65535).astype(np.uint16)
