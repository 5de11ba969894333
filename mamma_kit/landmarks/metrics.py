"""Landmark metrics shared by training-time evaluation and `mamma-kit eval`."""

from __future__ import annotations

import numpy as np
from scipy.stats import rankdata


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float | None:
    """Area under the ROC curve (Mann-Whitney U with tied ranks); None if one class is absent."""
    s = np.asarray(scores, np.float64).ravel()
    y = np.asarray(labels).ravel() > 0.5
    n_pos, n_neg = int(y.sum()), int((~y).sum())
    if n_pos == 0 or n_neg == 0:
        return None
    r = rankdata(s)
    return float((r[y].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def landmark_metrics(xy_pred: np.ndarray, xy_gt: np.ndarray, box_h: np.ndarray, vis_gt: np.ndarray,
                     vis_prob: np.ndarray, contact_gt: np.ndarray | None = None, contact_prob: np.ndarray | None = None,
                     floor_gt: np.ndarray | None = None, floor_prob: np.ndarray | None = None) -> dict:
    """Errors over N person instances x L landmarks.

    xy_* (N, L, 2) px; box_h (N,) px (the person's tight box height); vis_gt / vis_prob (N, L).
    """
    err = np.linalg.norm(np.asarray(xy_pred, np.float64) - np.asarray(xy_gt, np.float64), axis=-1)  # (N, L)
    rel = 100.0 * err / np.maximum(np.asarray(box_h, np.float64), 1e-6)[:, None]
    vis = np.asarray(vis_gt) > 0.5
    ok = np.isfinite(err)
    out = {
        "instances": int(err.shape[0]),
        "error_px_all": _mean(err[ok]), "error_px_visible": _mean(err[ok & vis]),
        "median_px_visible": _median(err[ok & vis]),
        "error_pct_box_all": _mean(rel[ok]), "error_pct_box_visible": _mean(rel[ok & vis]),
        "visibility_accuracy": _mean(((np.asarray(vis_prob) > 0.5) == vis)[ok]),
    }
    if contact_gt is not None and contact_prob is not None:
        out["contact_auc"] = roc_auc(np.asarray(contact_prob)[ok], np.asarray(contact_gt)[ok])
        out["contact_positives"] = int((np.asarray(contact_gt)[ok] > 0.5).sum())
    if floor_gt is not None and floor_prob is not None:
        out["floor_contact_auc"] = roc_auc(np.asarray(floor_prob)[ok], np.asarray(floor_gt)[ok])
        out["floor_contact_positives"] = int((np.asarray(floor_gt)[ok] > 0.5).sum())
    return out


def _mean(x: np.ndarray) -> float | None:
    return float(np.mean(x)) if np.size(x) else None


def _median(x: np.ndarray) -> float | None:
    return float(np.median(x)) if np.size(x) else None
