"""Clocks the rig already knows: cameras on one clock (genlock, a lab's synchronised cameras) and
rigs that log every frame's time in a file (Caliscope's timestamps.csv: sync_index, cam_id,
frame_time).

``synced_clocks`` says "these cameras share a clock" (offset 0, rate 0) and checks that the
videos' own timestamps do not contradict it; ``timestamp_clocks`` fits each camera's clock model
to the logged frame times (a line through its frames' container times against the log's times).
"""

from __future__ import annotations

import csv
import re
from pathlib import Path
from typing import Mapping

import numpy as np

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError

# videos of one shared clock that start more than this many frame periods apart are worth a warning
# (a genlocked rig starts recording together; a large start gap suggests separate clocks)
START_GAP_FRAMES = 2.0


def synced_clocks(timestamps: Mapping[str, np.ndarray]) -> tuple[dict[str, ClockModel], dict, list[str]]:
    """Identity clocks for cameras whose frame timestamps share one clock.
    -> (clocks, per-camera diagnostics, warnings)."""
    warnings: list[str] = []
    starts = {n: float(ts[0]) for n, ts in timestamps.items() if len(ts)}
    periods = [float(np.median(np.diff(ts))) for ts in timestamps.values() if len(ts) > 1]
    period = min(periods) if periods else 0.0
    gap = max(starts.values()) - min(starts.values()) if starts else 0.0
    if period and gap > START_GAP_FRAMES * period:
        warnings.append(f"--method synced: the videos' first frames are {gap * 1e3:.1f} ms apart on their own "
                        f"timestamps ({gap / period:.1f} frames); if the cameras were not on one clock, sync by "
                        "clap, LTC, timecode or motion instead")
    clocks = {n: ClockModel(0.0, 0.0, "synced", 1.0) for n in timestamps}
    diag = {n: {"first_frame_s": round(starts.get(n, 0.0), 6), "frames": int(len(ts))}
            for n, ts in timestamps.items()}
    return clocks, diag, warnings


def read_timestamps_csv(path: Path) -> dict[str, np.ndarray]:
    """cam_id -> frame times (s) in time order, from a CSV with columns cam_id and frame_time
    (Caliscope's timestamps.csv; sync_index, if present, is not needed)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"timestamps file not found: {path}", "check the path given to --timestamps")
    try:
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise UserError(f"{path.name} is not a readable CSV ({e})", "pass a CSV with cam_id and frame_time") from None
    if not rows or not {"cam_id", "frame_time"} <= set(rows[0]):
        raise UserError(f"{path.name} has no cam_id and frame_time columns",
                        "pass a CSV with a header row holding cam_id and frame_time (one row per frame)")
    out: dict[str, list[float]] = {}
    for i, r in enumerate(rows, start=2):
        try:
            out.setdefault(str(r["cam_id"]).strip(), []).append(float(r["frame_time"]))
        except (TypeError, ValueError):
            raise UserError(f"{path.name} line {i}: frame_time '{r.get('frame_time')}' is not a number",
                            "fix that line") from None
    return {k: np.sort(np.asarray(v, np.float64)) for k, v in out.items()}


def match_camera_ids(names: list[str], ids: list[str], path: Path) -> dict[str, str]:
    """Camera name -> the file's cam_id: the same text, else the number the name ends with."""
    out = {}
    for n in names:
        if n in ids:
            out[n] = n
            continue
        m = re.search(r"(\d+)$", n)
        hit = [i for i in ids if m and i.isdigit() and int(i) == int(m.group(1))]
        if not hit:
            raise UserError(f"{Path(path).name} has no rows for camera {n} (cam_id values: {', '.join(sorted(ids))})",
                            "name the cameras as the file does, or pass the rig's own timestamps file")
        out[n] = hit[0]
    return out


def timestamp_clocks(timestamps: Mapping[str, np.ndarray], path: Path, reference: str
                     ) -> tuple[dict[str, ClockModel], dict]:
    """Each camera's clock from the logged time of each of its frames.

    Per camera c, its frames' logged times are fitted as a_c t_c + b_c over its own container
    times t_c; the reference camera's t_ref = (file time - b_ref) / a_ref gives
    t_ref = (a_c / a_ref) t_c + (b_c - b_ref) / a_ref. -> (clocks, per-camera diagnostics)."""
    logged = read_timestamps_csv(path)
    ids = match_camera_ids(list(timestamps), list(logged), path)
    fits, diag = {}, {}
    for n, ts in timestamps.items():
        lt = logged[ids[n]]
        if len(lt) != len(ts):
            raise UserError(f"{Path(path).name} lists {len(lt)} frames for camera {n} but its video has {len(ts)}",
                            "pass the timestamps file recorded with these videos")
        A = np.column_stack([ts - ts[0], np.ones_like(ts)])
        (a, b), *_ = np.linalg.lstsq(A, lt, rcond=None)
        b -= a * ts[0]
        resid = lt - (a * ts + b)
        fits[n] = (a, b)
        period = float(np.median(np.diff(ts))) if len(ts) > 1 else 1.0
        rms = float(np.sqrt(np.mean(resid ** 2)))
        diag[n] = {"cam_id": ids[n], "frames": int(len(ts)), "residual_rms_ms": round(rms * 1e3, 4),
                   "residual_max_ms": round(float(np.abs(resid).max()) * 1e3, 4)}
        # confidence: 1 while the log's times sit on the container's within a tenth of a frame
        diag[n]["confidence"] = float(np.clip(1.0 - rms / (0.5 * period), 0.0, 1.0))
    ar, br = fits[reference]
    clocks = {n: ClockModel(offset=float((b - br) / ar), rate=float(a / ar - 1.0), source="timestamps",
                            confidence=diag[n]["confidence"]) for n, (a, b) in fits.items()}
    return clocks, diag
