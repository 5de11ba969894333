"""Robust line fits and clock-model composition (float64 throughout)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.core.clock import ClockModel


@dataclass
class LineFit:
    """y = slope * x + intercept, fitted robustly; ``inlier_n`` marks points kept."""
    slope: float
    intercept: float
    residual_n: np.ndarray
    inlier_n: np.ndarray
    rms: float
    slope_sd: float
    intercept_sd: float


def robust_line(x_n, y_n, w_n=None, fix_slope: float | None = None, scale_floor: float = 1e-6,
                n_iter: int = 8, reject_k: float = 5.0) -> LineFit:
    """Weighted least squares with Huber re-weighting and hard rejection of points beyond
    ``reject_k`` robust standard deviations (but never below ``scale_floor``).

    x is centred internally so slope and intercept are well conditioned over long takes.
    With ``fix_slope`` only the intercept is fitted.
    """
    x = np.asarray(x_n, float)
    y = np.asarray(y_n, float)
    w0 = np.ones_like(x) if w_n is None else np.asarray(w_n, float)
    xc = float(np.average(x, weights=w0)) if len(x) else 0.0
    u = x - xc
    inl = np.ones(len(x), bool)
    w = w0.copy()
    slope, icpt_c = (fix_slope or 0.0), 0.0
    for _ in range(n_iter):
        ww = w * inl
        if fix_slope is None and np.sum(ww > 0) >= 2 and np.ptp(u[ww > 0]) > 0:
            A = np.stack([u, np.ones_like(u)], 1)
            sw = np.sqrt(ww)
            sol, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
            slope, icpt_c = float(sol[0]), float(sol[1])
        else:
            slope = fix_slope if fix_slope is not None else 0.0
            icpt_c = float(np.sum(ww * (y - slope * u)) / max(np.sum(ww), 1e-300))
        r = y - (slope * u + icpt_c)
        s = 1.4826 * np.median(np.abs(r[inl])) if inl.any() else 0.0
        s = max(s, scale_floor)
        inl = np.abs(r) <= reject_k * s
        hub = np.minimum(1.0, 1.5 * s / np.maximum(np.abs(r), 1e-300))
        w = w0 * hub
    r = y - (slope * u + icpt_c)
    n_in = int(inl.sum())
    rms = float(np.sqrt(np.mean(r[inl] ** 2))) if n_in else float("nan")
    # standard errors from the inlier scatter
    sig = rms if n_in > 2 else float("nan")
    su = u[inl]
    sxx = float(np.sum((su - su.mean()) ** 2)) if n_in else 0.0
    slope_sd = sig / np.sqrt(sxx) if sxx > 0 and fix_slope is None else (0.0 if fix_slope is not None else float("inf"))
    icpt_sd = sig / np.sqrt(max(n_in, 1))
    intercept = icpt_c - slope * xc
    return LineFit(slope, intercept, r, inl, rms, float(slope_sd), float(np.hypot(icpt_sd, slope_sd * xc)
                                                                           if np.isfinite(slope_sd) else icpt_sd))


def relative_clock(cam_to_common: ClockModel, ref_to_common: ClockModel) -> tuple[float, float]:
    """(offset, rate) of a camera relative to the reference camera when both map to a common
    clock (timecode or scene): t_refcam = (1 + rate) t_cam + offset."""
    s = (1.0 + cam_to_common.rate) / (1.0 + ref_to_common.rate)
    return (cam_to_common.offset - ref_to_common.offset) / (1.0 + ref_to_common.rate), s - 1.0
