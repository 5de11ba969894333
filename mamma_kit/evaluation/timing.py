"""Timing metrics: estimated clocks (timing.toml) against the true ones (gt/timing.toml).

The truth maps each camera to the scene's reference clock; the estimate maps each camera to
the reference *camera*. Both are compared as mappings to the estimate's reference camera:
true relative offset = (o_c - o_r) / (1 + a_r), relative rate = (1 + a_c) / (1 + a_r) - 1.
Offset errors are reported at camera time 0 and, when the videos are readable, as the
largest mapping error over the camera's recording (drift error included).
"""

from __future__ import annotations

import numpy as np

from mamma_kit.core.timingfile import read_timing
from mamma_kit.core.workspace import Workspace


def _relative(c, r) -> tuple[float, float]:
    return (c.offset - r.offset) / (1.0 + r.rate), (1.0 + c.rate) / (1.0 + r.rate) - 1.0


def evaluate(ws: Workspace) -> dict | None:
    gt_path = ws.gt_dir / "timing.toml"
    if not ws.timing.is_file() or not gt_path.is_file():
        return None
    est, info = read_timing(ws.timing)
    gt, _ = read_timing(gt_path)
    ref = info.get("reference") or next(iter(est))
    if ref not in gt:
        return {"error": f"reference camera {ref} has no ground truth"}
    spans = _spans(ws, list(est))
    cams = {}
    for n, e in est.items():
        if n not in gt:
            continue
        o_t, a_t = _relative(gt[n], gt[ref])
        d = {"offset_error_ms": (e.offset - o_t) * 1e3, "drift_error_ppm": (e.rate - a_t) * 1e6,
             "method": e.source, "confidence": e.confidence}
        if n in spans:
            t = np.linspace(*spans[n], 50)
            err = ((1 + e.rate) * t + e.offset) - ((1 + a_t) * t + o_t)
            d["max_mapping_error_ms"] = float(np.abs(err).max() * 1e3)
        cams[n] = d
    if not cams:
        return None
    return {
        "reference": ref,
        "cameras": cams,
        "worst_offset_error_ms": max(abs(d["offset_error_ms"]) for d in cams.values()),
        "worst_drift_error_ppm": max(abs(d["drift_error_ppm"]) for d in cams.values()),
        "worst_mapping_error_ms": max((d.get("max_mapping_error_ms", 0.0) for d in cams.values()), default=0.0),
    }


def _spans(ws: Workspace, names: list[str]) -> dict[str, tuple[float, float]]:
    """Each camera's recording span (first to last frame, camera time) when readable."""
    out = {}
    try:
        cap = ws.load_capture()
        from mamma_kit.video import VideoReader

        for n in names:
            if n in cap.cameras and cap.cameras[n].video.is_file():
                ts = VideoReader(cap.cameras[n].video).timestamps
                out[n] = (float(ts[0]), float(ts[-1]))
    except Exception:  # the spans only refine the report; a missing capture.toml is not an error here
        return {}
    return out
