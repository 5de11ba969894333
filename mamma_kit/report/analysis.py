"""Numbers behind the report's new figures: per-camera reprojection error of the fitted
bodies over time, and contact probabilities per person over time and per landmark.

Times are on the reference clock: a camera frame at camera time t was exposed at
``clock.to_ref(t)`` (timing.toml). The body at a camera frame's time is interpolated linearly
between the two fitted frames around it (ReportData.landmarks_at).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from mamma_kit.report.data import BLOCK, MIN_VIS, ReportData


@dataclass
class Series:
    """One curve: reference times (N,) and values (N,) (NaN where there is nothing)."""

    camera: str
    person: int
    t_ref: np.ndarray
    value: np.ndarray


def _quiet_nan(fn, *args, **kw):
    # all-NaN slices are expected (frames without the person); their result stays NaN
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return fn(*args, **kw)


def _blocks(lt):
    """(frame slice, columns with rows there, their arrays) over a camera's tracks, BLOCK frames at a time."""
    for a in range(0, lt.n_frames, BLOCK):
        b = min(a + BLOCK, lt.n_frames)
        cols, arr = lt.window(a, b, ("valid", "xy", "visibility", "contact", "floor_contact"))
        yield slice(a, b), cols, arr


def reprojection_over_time(data: ReportData) -> tuple[list[Series], list[list], list[str]]:
    """Per camera and person: the median reprojection error (px) per frame of the landmarks
    with visibility > MIN_VIS. Returns the curves, table rows [camera, person, frames, median,
    p90, landmarks] and notes on cameras that were left out. Each camera is read a block of
    frames at a time."""
    rig, model = data.rig, data.body_model
    L = len(model.landmark_ids)
    series, rows, notes = [], [], []
    for cam, lt in data.landmarks.items():
        if cam not in rig:
            notes.append(f"{cam}: not in calibration.toml")
            continue
        if lt.n != L:
            notes.append(f"{cam}: landmarks hold {lt.n} points, the body model {L}")
            continue
        if tuple(lt.image_size) != tuple(rig[cam].size):
            notes.append(f"{cam}: landmark image size differs from calibration.toml")
            continue
        t_ref = data.clock(cam).to_ref(lt.frame_times)
        people = [(p, data.track_columns(cam, p.id)) for p in data.people]
        people = [(p, cols) for p, cols in people if len(cols)]
        med = {p.id: np.full(len(t_ref), np.nan) for p, _ in people}
        errs: dict[int, list] = {p.id: [] for p, _ in people}
        for s, wcols, arr in _blocks(lt):
            for person, cols in people:
                sel = np.flatnonzero(np.isin(wcols, cols))
                if not len(sel):
                    continue
                X_tl3, inside = data.landmarks_at(person, t_ref[s])
                xy_tl2 = rig[cam].project(X_tl3)
                err_tkl = np.linalg.norm(xy_tl2[:, None] - arr["xy"][:, sel], axis=-1)
                use = (arr["visibility"][:, sel] > MIN_VIS) & arr["valid"][:, sel, None] & inside[:, None, None]
                use &= np.isfinite(err_tkl)
                err_tkl = np.where(use, err_tkl, np.nan)
                med[person.id][s] = _quiet_nan(np.nanmedian, err_tkl.reshape(len(err_tkl), -1), axis=1)
                errs[person.id].append(err_tkl[use])
        for person, _ in people:
            med_t = med[person.id]
            if not np.isfinite(med_t).any():
                continue
            series.append(Series(cam, person.id, t_ref, med_t))
            e = np.concatenate(errs[person.id])
            rows.append([cam, person.id, int(np.isfinite(med_t).sum()), float(np.median(e)),
                         float(np.percentile(e, 90)), int(e.size)])
    return series, rows, notes


def per_frame_means(data: ReportData, cam: str, pids: list[int]) -> dict[int, dict[str, np.ndarray]]:
    """{person: {"contact", "floor_contact": (T,)}}: the mean over the person's landmarks in one view
    of each probability per frame (NaN where absent)."""
    lt = data.landmarks[cam]
    cols = {p: data.track_columns(cam, p) for p in pids}
    out = {p: {f: np.full(lt.n_frames, np.nan) for f in ("contact", "floor_contact")} for p in pids}
    for s, wcols, arr in _blocks(lt):
        for p in pids:
            sel = np.flatnonzero(np.isin(wcols, cols[p]))
            if not len(sel):
                continue
            for f in ("contact", "floor_contact"):
                p_tkl = np.where(arr["valid"][:, sel, None], arr[f][:, sel], np.nan)
                out[p][f][s] = _quiet_nan(np.nanmean, p_tkl.reshape(len(p_tkl), -1), axis=1)
    return out


def nearest_frame(t_c: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index (N,) of the frame in sorted times t_c nearest to each t, and whether it lies within
    half a frame interval."""
    if len(t_c) == 1:
        return np.zeros(len(t), int), np.abs(t - t_c[0]) < 1e-6
    j = np.clip(np.searchsorted(t_c, t), 1, len(t_c) - 1)
    j = np.where(np.abs(t_c[j - 1] - t) <= np.abs(t_c[j] - t), j - 1, j)
    return j, np.abs(t_c[j] - t) <= 0.5 * float(np.median(np.diff(t_c))) + 1e-9


def contact_over_time(data: ReportData) -> tuple[np.ndarray, dict[int, dict[str, np.ndarray]]]:
    """Mean person-contact and floor-contact probability per person on a common time grid.

    The grid is the reference camera's frames (timing.toml's reference if it has landmarks).
    Each view's value at a grid time is its nearest frame within half a frame interval;
    returns grid (N,) and {person: {"contact": (C, N), "floor": (C, N)}} over the C views."""
    cams = list(data.landmarks)
    ref = data.timing[1].get("reference") if data.timing else None
    ref = ref if ref in data.landmarks else cams[0]
    grid = data.clock(ref).to_ref(data.landmarks[ref].frame_times)
    pids = sorted({p for c in cams for p in data.person_of_track(c).values()})
    out = {p: {"contact": np.full((len(cams), len(grid)), np.nan),
               "floor": np.full((len(cams), len(grid)), np.nan)} for p in pids}
    for ci, cam in enumerate(cams):
        t_c = data.clock(cam).to_ref(data.landmarks[cam].frame_times)
        if not len(t_c):
            continue
        j, near = nearest_frame(t_c, grid)
        means = per_frame_means(data, cam, pids)
        for p in pids:
            for key, fld in (("contact", "contact"), ("floor", "floor_contact")):
                out[p][key][ci] = np.where(near, means[p][fld][j], np.nan)
    return grid, out


def contact_per_landmark(data: ReportData) -> tuple[np.ndarray, np.ndarray, int]:
    """(L,) mean person-contact and floor-contact probability of every landmark over all views,
    frames and matched tracks, and the number of observations averaged."""
    L = {lt.n for lt in data.landmarks.values()}
    if len(L) != 1:
        return np.zeros(0), np.zeros(0), 0
    L = L.pop()
    sums = np.zeros((2, L))
    n = 0
    for cam, lt in data.landmarks.items():
        matched = np.flatnonzero([int(t) in data.person_of_track(cam) for t in lt.track_ids])
        for _, wcols, arr in _blocks(lt):
            sel = np.flatnonzero(np.isin(wcols, matched))
            ok_tk = arr["valid"][:, sel]
            for i, fld in enumerate(("contact", "floor_contact")):
                sums[i] += np.nan_to_num(arr[fld][:, sel][ok_tk]).sum(0)
            n += int(ok_tk.sum())
    return sums[0] / max(n, 1), sums[1] / max(n, 1), n
