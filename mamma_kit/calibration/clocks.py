"""Shared clocks found from the files: when are board videos known to be synchronised?

Two sources say so without anyone passing ``--synced``:

- a timestamps file: Caliscope's ``timestamps.csv`` beside the videos (or one given with
  ``--timestamps FILE``), columns ``sync_index, cam_id, frame_time`` (``frame_index``
  optional). Rows that share a sync_index were taken at the same instant; each camera's
  rows in time order are its frames in order. Every frame of a sync_index gets that
  index's time (the median of its rows' frame_time), so frames taken together match
  exactly; a frame stamped more than ``max_skew_s`` away from its index's median (the
  recorder grouped frames that were not taken together) keeps its own stamp;
- the videos' own frame timestamps, when they are stamped on one absolute clock: every
  video starts well after zero (a wall or session clock, not the container's usual 0) and
  the videos overlap in time. Videos that all start at 0 (phones) say nothing.

The result is a per-camera array of shared-clock times, one per video frame, and a
sentence saying where it came from.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mamma_kit.core.errors import UserError

TIMESTAMPS_NAME = "timestamps.csv"
ABSOLUTE_START_S = 1.0  # a video whose first frame is stamped later than this is on an absolute clock


@dataclass
class SharedClock:
    # camera -> (T,) shared-clock seconds of each video frame; None: the videos' own frame
    # timestamps are the shared clock
    frame_times: dict[str, np.ndarray] | None
    source: str  # "timestamps file" | "video timestamps"
    detail: str  # one sentence for the log and the diagnostics


def find_timestamps_file(videos: dict[str, Path]) -> Path | None:
    """timestamps.csv in the folder that holds every video, if there is one."""
    folders = {Path(p).resolve().parent for p in videos.values()}
    if len(folders) != 1:
        return None
    f = folders.pop() / TIMESTAMPS_NAME
    return f if f.is_file() else None


def _camera_of(cam_id: str, names: list[str]) -> str | None:
    """The camera a timestamps row's cam_id means: the name itself, cam_<id>, cam<id>, or the
    one name whose trailing number is the id."""
    for cand in (cam_id, f"cam_{cam_id}", f"cam{cam_id}"):
        if cand in names:
            return cand
    if cam_id.isdigit():
        hits = [n for n in names if (m := re.search(r"(\d+)$", n)) and int(m.group(1)) == int(cam_id)]
        if len(hits) == 1:
            return hits[0]
    return None


def read_timestamps(path: Path, n_frames: dict[str, int], max_skew_s: float = 0.015) -> SharedClock:
    """Per-camera shared-clock times from a Caliscope-style timestamps.csv (see the module
    docstring); ``n_frames`` is each camera's frame count, which the file must match."""
    path = Path(path)
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"cannot read the timestamps file {path} ({e})", "pass a CSV file with --timestamps") from None
    need = {"sync_index", "cam_id", "frame_time"}
    have = set(rows[0]) if rows else set()
    if not rows or not need <= have:
        raise UserError(f"{path.name}: expected the columns sync_index, cam_id, frame_time "
                        f"(found {', '.join(sorted(have)) or 'no rows'})",
                        "pass a Caliscope timestamps.csv, or calibrate with --synced or --timing instead")
    names = list(n_frames)
    per_cam: dict[str, list[tuple[float, int, int]]] = {}
    unknown = set()
    for k, r in enumerate(rows):
        try:
            t, si = float(r["frame_time"]), int(float(r["sync_index"]))
            fi = int(float(r["frame_index"])) if r.get("frame_index") not in (None, "") else -1
        except (TypeError, ValueError):
            raise UserError(f"{path.name}: row {k + 2} is not numeric ({r})", "fix the file") from None
        cam = _camera_of(str(r["cam_id"]).strip(), names)
        if cam is None:
            unknown.add(str(r["cam_id"]).strip())
            continue
        per_cam.setdefault(cam, []).append((t, si, fi))
    missing = [n for n in names if n not in per_cam]
    if missing:
        raise UserError(f"{path.name} has no rows for camera {', '.join(missing)}"
                        + (f" (its cam_ids: {', '.join(sorted(unknown))})" if unknown else ""),
                        "name the videos cam_<cam_id>.mp4, or calibrate with --synced or --timing instead")
    sync_times: dict[int, list[float]] = {}
    for lst in per_cam.values():
        for t, si, _ in lst:
            sync_times.setdefault(si, []).append(t)
    t_sync = {si: float(np.median(v)) for si, v in sync_times.items()}
    out = {}
    for n in names:
        lst = sorted(per_cam[n], key=lambda r: (r[2], r[0]) if r[2] >= 0 else (0, r[0]))
        if len(lst) != n_frames[n]:
            raise UserError(f"{path.name} lists {len(lst)} frames of camera {n} but its video holds {n_frames[n]}",
                            "pass the timestamps file written with these very videos, or calibrate with --synced")
        out[n] = np.array([t_sync[si] if abs(t - t_sync[si]) <= max_skew_s else t for t, si, _ in lst])
    shared = sum(1 for v in sync_times.values() if len(v) > 1)
    return SharedClock(out, "timestamps file", f"shared clocks from {path.name} ({shared} instants seen by "
                                               f"several cameras)")


def shared_clock_from_videos(timestamps: dict[str, np.ndarray]) -> SharedClock | None:
    """The videos' own frame timestamps, when they say the videos share one clock (every
    video starts after ABSOLUTE_START_S and each overlaps all others by half its length)."""
    if len(timestamps) < 2:
        return None
    starts = {n: float(t[0]) for n, t in timestamps.items() if len(t)}
    if len(starts) != len(timestamps) or min(starts.values()) <= ABSOLUTE_START_S:
        return None
    spans = {n: (float(t[0]), float(t[-1])) for n, t in timestamps.items()}
    for a, (a0, a1) in spans.items():
        for b, (b0, b1) in spans.items():
            if a < b:
                ov = min(a1, b1) - max(a0, b0)
                if ov < 0.5 * min(a1 - a0, b1 - b0) or ov <= 0:
                    return None
    return SharedClock(None, "video timestamps",
                       "shared clocks from the videos' frame timestamps (every video is stamped on one absolute "
                       f"clock, starting {min(starts.values()):.3f}-{max(starts.values()):.3f} s)")
