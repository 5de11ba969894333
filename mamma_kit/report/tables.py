"""The report's captions and tables: pure functions from what a workspace holds to the rows of a
``Section.table`` (columns, rows, caption) or a caption string. report/build.py puts them in
sections with the figures."""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_toml
from mamma_kit.report.data import ReportData
from mamma_kit.report.html import Table

# pictures other commands write, in the order they read best
CALIB_ORDER = ("rig", "connectivity")
SYNC_ORDER = ("offsets", "residuals", "peaks", "agreement")

TableSpec = tuple[list[str], list[list], str]  # columns, rows, caption: the arguments of Section.table


def n_of(count: int, noun: str, plural: str = "s") -> str:
    """'1 camera', '2 cameras'."""
    return f"{count} {noun}{'' if count == 1 else plural}"


def ordered_pngs(folder: Path, first: tuple[str, ...]) -> list[Path]:
    """The PNGs in ``folder``: those named in ``first`` in that order, then the rest by name."""
    pngs = sorted(folder.glob("*.png")) if folder.is_dir() else []
    rank = {n: i for i, n in enumerate(first)}
    return sorted(pngs, key=lambda p: (rank.get(p.stem, len(rank)), p.stem))


def written(path: Path) -> str:
    """The file's modification time as 'YYYY-MM-DD HH:MM'."""
    # non-breaking hyphens and space: the date stays on one line in narrow table columns
    return _dt.datetime.fromtimestamp(path.stat().st_mtime).strftime("%Y\u2011%m\u2011%d\u00a0%H:%M")


def calib_caption(stem: str) -> str:
    if stem.startswith("camera_"):
        return (f"{stem[7:]}: board corner residuals over the image, per-view errors and coverage "
                f"(from `mamma-kit calibrate`).")
    return {"rig": "The calibrated rig with the board poses (from `mamma-kit calibrate`).",
            "connectivity": "Which cameras share still-board views, seen from above."}.get(stem, stem)


def sync_caption(stem: str) -> str:
    return {"offsets": "Clock offset and drift per camera, with confidence.",
            "residuals": "Residuals of the clock fit per event.",
            "peaks": "Correlation peaks of the sync signal.",
            "agreement": "Agreement between sync methods."}.get(stem, stem)


# captions of the figures the report draws
AFFINITIES_CAPTION = ("Track affinities across views (epipolar agreement of the landmarks), grouped by person; right: "
                      "views per person.")
REPROJECTION_CAPTION = (
    "Per camera and person: the median distance (px) between the observed landmarks with visibility "
    "> 0.5 and the fitted body's landmarks projected with calibration.toml, per frame. Each camera "
    "frame's time is mapped to the reference clock with timing.toml; the body at that time is "
    "interpolated linearly between the two nearest fitted frames. Dashed: the camera's median.")
CONTACT_TIME_CAPTION = (
    "Per person: the predicted probability that a landmark touches another person (left) or the "
    "floor (right), averaged over the 512 landmarks; line: mean over the views seeing the person at "
    "that reference time (nearest frame of each view), band: range over the views.")
GT_CAPTION = ("MPJPE (all 55 joints, body, hands), PA-MPJPE (after Procrustes alignment) and per-vertex error per "
              "person, in mm, against gt/.")


def rig_caption(names: list[str], with_people: bool) -> str:
    return (f"{len(names)} cameras (frusta {', '.join(names)})"
            + (" and the fitted people: the middle frame's skeleton and the mean pelvis position; right: "
               "pelvis paths on the floor" if with_people else "") + ". World frame: Z up, floor at z = 0.")


def contact_landmarks_caption(n: int) -> str:
    return (f"Which landmarks are in contact most: the landmarks on the rest-pose body coloured by their mean "
            f"probability over {n} observations (views x frames x matched tracks).")


def overlay_caption(camera: str, times: list[float]) -> str:
    return (f"{camera}: the fitted meshes (one colour per person) over frames at reference times "
            f"{', '.join(f'{t:.2f}' for t in times)} s; bodies interpolated between fitted frames.")


def overlay_video_caption(info: dict) -> str:
    return (f"{', '.join(info['cameras'])}: {info['frames']} frames ({info['seconds']:.1f} s at "
            f"{info['fps']:.0f} fps) from the start of the fitted span, "
            f"{info['size'][0]}x{info['size'][1]} px.")


# ---- overview ------------------------------------------------------------------------------
def overview_table(ws, d: ReportData) -> Table:
    """One row per stage: its output, whether it is there, the command that made it and when."""
    first = lambda m: next(iter(m.values())) if m else None  # noqa: E731
    stages = [
        ("calibrate", ws.calibration, lambda: "calibration.toml",
         lambda: d.calibration and d.calibration[1].get("producer")),
        ("sync", ws.timing, lambda: "timing.toml",
         lambda: ws.timing.is_file() and read_toml(ws.timing, "timing file").get("producer")),
        ("track", ws.masks_dir, lambda: f"masks/ ({n_of(len(d.mask_tracks), 'camera')})",
         lambda: d.mask_tracks and first(d.mask_tracks).producer),
        ("keypoints", ws.keypoints_dir, lambda: f"keypoints/ ({n_of(len(d.keypoints), 'camera')})",
         lambda: d.keypoints and first(d.keypoints).producer),
        ("landmarks", ws.landmarks_dir,
         lambda: f"landmarks/ ({n_of(len(d.landmarks), 'camera')}, source "
                 f"{', '.join(sorted({x.source for x in d.landmarks.values()})) or '?'})",
         lambda: d.landmarks and first(d.landmarks).producer),
        ("match", ws.identities, lambda: "identities.json", lambda: d.identities and d.identities.producer),
        ("fit", ws.smplx_dir, lambda: f"smplx/ ({n_of(len(d.people), 'person')})",
         lambda: d.people and d.people[0].result.producer),
    ]
    present = {"calibrate": ws.calibration.is_file(), "sync": ws.timing.is_file(),
               "track": any(ws.masks_dir.glob("*.npz")), "keypoints": any(ws.keypoints_dir.glob("*.npz")),
               "landmarks": any(ws.landmarks_dir.glob("*.npz")),
               "match": ws.identities.is_file(), "fit": bool(ws.person_files())}
    rows = []
    for stage, path, what, prod in stages:
        if not present[stage]:
            rows.append([stage, path.name + ("/" if path.suffix == "" else ""), "missing", "—", "—"])
            continue
        try:
            rows.append([stage, what(), "done", (prod() or {}).get("command") or "—", written(path)])
        except UserError as e:
            rows.append([stage, path.name, f"unreadable: {e.message}", "—", written(path)])
    return Table(["stage", "output", "status", "produced by", "written"], rows)


# ---- 1. rig and calibration ------------------------------------------------------------------
def calibration_tables(rig, diag: dict) -> list[TableSpec]:
    """The cameras table (lens, rms, views, cross-validation) and the rig's summary."""
    rows = []
    for c in rig:
        cd = diag["cameras"].get(c.name, {})
        cv = cd.get("cross_validation_px") or {}
        rows.append([c.name, f"{c.width}x{c.height}", c.model, float(c.K[0, 0]), cd.get("rms_px"),
                     cd.get("intrinsics_rms_px"), cd.get("views"), cd.get("shared_views"),
                     cv.get("median_px"), cv.get("p95_px")])
    cameras = (["camera", "size", "lens", "focal (px)", "rms (px)", "intrinsics rms (px)", "views",
                "shared views", "cross-val. median (px)", "cross-val. p95 (px)"], rows, "cameras")
    r = diag["rig"]
    keys = [("rms_px", "bundle-adjusted rms (px)"), ("model", "lens model"), ("reference_camera", "reference"),
            ("timing", "board timing"), ("observations", "corner observations"), ("outliers", "outliers"),
            ("source", "source")]
    rig_rows = [[label, r[k]] for k, label in keys if k in r]
    if isinstance(r.get("world"), dict) and r["world"].get("source"):
        rig_rows.append(["world frame from", r["world"]["source"]])
    return [cameras, (["rig", "value"], rig_rows, "rig")]


# ---- 2. synchronisation --------------------------------------------------------------------
def sync_tables(clocks: dict, info: dict) -> list[TableSpec]:
    """The clocks per camera (offset, drift, method, residuals) and the sync summary."""
    rows = []
    for n, clk in clocks.items():
        cd = info["cameras"].get(n, {})
        per = cd.get(clk.source, {}) if isinstance(cd.get(clk.source), dict) else {}
        rows.append([n, clk.offset * 1e3, clk.rate_ppm, clk.source, clk.confidence,
                     per.get("residual_rms_ms"), per.get("events")])
    dg = info.get("diagnostics", {})
    return [(["camera", "offset (ms)", "drift (ppm)", "method", "confidence", "residual rms (ms)", "events"],
             rows, f"clocks: t_ref = (1 + drift) t_cam + offset, reference {info.get('reference')}"),
            (["sync", "value"], [[k, v] for k, v in (("method", info.get("method")),
                                                     ("methods tried", dg.get("methods_tried")),
                                                     ("methods that worked", dg.get("methods_ok")),
                                                     ("chosen", dg.get("chosen"))) if v is not None], "summary")]


# ---- 3. tracks and matching ------------------------------------------------------------------
def track_table(mask_tracks: dict) -> TableSpec:
    """Tracks, frames and track ids per camera."""
    return (["camera", "tracks", "frames", "frames with a person", "track ids"],
            [[c, len(m.track_ids), len(m.frame_times), int(m.present.any(1).sum()),
              [int(t) for t in m.track_ids]] for c, m in mask_tracks.items()], "person tracks per view")


def keypoint_table(keypoints: dict, mask_tracks: dict) -> TableSpec:
    """Per camera: person-frames with keypoints against tracked person-frames, and the median score
    (``keypoints``: camera -> core.filled.CameraTracks)."""
    rows = []
    for c, k in keypoints.items():
        r = k.rows(0, k.n_frames, ("valid", "score"))
        score = r["score"][r["valid"].astype(bool)]
        rows.append([c, int(len(score)), int(mask_tracks[c].present.sum()) if c in mask_tracks else "—",
                     f"{np.median(score):.2f}" if len(score) else "—"])
    return (["camera", "person-frames with keypoints", "tracked person-frames", "median pose score"], rows,
            "BlazePose keypoints per view")


def identity_tables(ident) -> list[TableSpec]:
    """Which tracks make each person, and the tracks left unassigned (with why)."""
    out = [(["person", "views", "tracks (camera:track, frames)"],
            [[p["id"], p["views"], ", ".join(f"{t['camera']}:{t['track']} ({t['frames']})" for t in p["tracks"])]
             for p in ident.persons()], f"{n_of(len(ident.person_ids), 'person')}, "
                                        f"{n_of(len(ident.unassigned), 'unassigned track')}, "
                                        f"{n_of(len(ident.rejected), 'rejected match', 'es')}")]
    if ident.unassigned:
        out.append((["camera", "track", "why unassigned"],
                    [[u.get("camera"), u.get("track"), u.get("reason")] for u in ident.unassigned], "unassigned"))
    return out


# ---- 4. fit --------------------------------------------------------------------------------
def fit_report_tables(rep: dict) -> list[TableSpec]:
    """smplx/fit_report.json as tables: summary, stages, reprojection per camera, people, and the
    views set aside where there were any."""
    span = rep.get("time_span_s") or [None, None]
    st = rep.get("stage_stats", {})
    aside = (rep.get("views_set_aside") or {}).get("frames") or {}
    extra = [(["camera", "person", "frames: keypoints", "landmarks"],
              [[c, p, n.get("keypoints"), n.get("landmarks")] for c, ps in aside.items() for p, n in ps.items()],
              "views set aside: their keypoints missed the other views' consensus (fitting/views.py)")] if aside else []
    return [
        (["fit", "value"], [["body model", rep.get("body_model")], ["cameras", rep.get("cameras")],
                            ["reference clock", rep.get("reference")], ["frames", rep.get("frames")],
                            ["time span (s)", span], ["stages", rep.get("stages")],
                            ["seconds", rep.get("seconds")], ["threads", rep.get("threads")]], "summary"),
        (["stage", "wall (s)", "cpu (s)", "energy start", "energy end", "iterations"],
         [[k, v.get("wall_s"), v.get("cpu_s"), v.get("energy_start"), v.get("energy_end"),
           v.get("iterations")] for k, v in st.items()], "stages"),
        (["camera", "mean (px)", "median (px)", "p90 (px)", "landmarks"],
         [[c, v.get("mean"), v.get("median"), v.get("p90"), v.get("landmarks")]
          for c, v in rep.get("reprojection_px", {}).items()], "reprojection (fit_report.json)"),
        (["person", "frames observed", "file"],
         [[p.get("id"), p.get("frames_observed"), p.get("file")] for p in rep.get("persons", [])], "people"),
    ] + extra


# ---- 7. ground truth -------------------------------------------------------------------------
def metric_tables(group: str, metrics: dict) -> list[TableSpec]:
    """One evaluation group as tables: its scalars as name/value rows, every dict of dicts
    (e.g. per camera) and list of dicts (e.g. per person) as a table of its own."""
    out, scalars = [], []
    for k, v in metrics.items():
        if isinstance(v, dict) and v and all(isinstance(x, dict) for x in v.values()):
            cols = list(dict.fromkeys(c for x in v.values() for c in x))
            out.append(([k.rstrip("s") if k.endswith("s") else k] + cols,
                        [[name] + [x.get(c) for c in cols] for name, x in v.items()], f"{group}: {k}"))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            cols = list(dict.fromkeys(c for x in v for c in x))
            out.append((cols, [[x.get(c) for c in cols] for x in v], f"{group}: {k}"))
        elif isinstance(v, dict):  # a few named numbers: one row each
            scalars += [[f"{k}.{kk}", x] for kk, x in v.items()]
        else:
            scalars.append([k, v])
    if scalars:
        out.insert(0, (["metric", "value"], scalars, group))
    return out


CHECKS_CAPTION = ("physical checks (fitting/checks.py): impossible bodies (at or behind a camera that sees them, "
                  "under the floor, faster than a sprinter, two persons in one place) and doubtful ones, with "
                  "their likely cause; see docs/fitting.md")


def checks_table(checks: dict) -> tuple[TableSpec | None, str]:
    """The fit's physical-check flags as a table (None when nothing was flagged) and a one-line verdict."""
    flags = sorted(checks.get("flags", []), key=lambda f: (f["severity"] != "impossible", f["person"], f["frames"][0]))
    verdict = ("physical checks: every fitted body is possible" + ("" if checks.get("floor_known") else
                                                                    " (floor unknown: not checked against it)")
               if not flags else f"physical checks: {checks['impossible_frames']} impossible and "
               f"{checks['doubtful_frames']} doubtful person-frames")
    if not flags:
        return None, verdict
    rows = [[f["person"], f["check"].replace("_", " "), f["severity"], f"{f['frames'][0]}-{f['frames'][1]}",
             f"{f['times_s'][0]:.2f}-{f['times_s'][1]:.2f}", f["what"], f["cause"]] for f in flags]
    return (["person", "check", "severity", "frames", "time (s)", "measured", "likely cause"], rows, CHECKS_CAPTION), verdict
