"""The capture report: one self-contained HTML page of everything a workspace holds.

``build_report(ws)`` writes ``report/index.html`` with every picture embedded (base64 data
URIs; no network, no external scripts or styles) and returns a JSON-able summary. Sections
appear as far as their inputs exist; a missing input is named with the command that makes it:

1. rig and calibration   calibration.toml, report/calibration/*.png, smplx/ (people in the rig)
2. synchronisation       timing.toml, report/sync/*.png
3. tracks and matching   masks/, report/tracks/, identities.json, report/match/affinities.png
4. fit                   smplx/, fit_report.json, reprojection error per camera over time
5. contact               landmarks/: contact probabilities over time and per landmark
6. overlays              the fitted meshes over the videos (PNG stills and a short MP4)
7. ground truth          gt/ (synthetic workspaces): `mamma-kit eval`'s metrics

New figures are written as PNGs under report/ (rig/, fit/, contact/, overlays/, gt/) besides
being embedded. ``rerun=True`` also writes report/recording.rrd (needs rerun-sdk).
"""

from __future__ import annotations

import datetime as _dt
import time
from pathlib import Path

import numpy as np

from mamma_kit import __version__
from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import atomic_write_text, read_toml
from mamma_kit.report.data import ReportData
from mamma_kit.report.html import Section, Table, render_page

# pictures other commands write, in the order they read best
CALIB_ORDER = ("rig", "connectivity")
SYNC_ORDER = ("offsets", "residuals", "peaks", "agreement")
MIN_CONTACT = 0.01  # landmarks below this mean probability are not listed as "most in contact"


def _ordered_pngs(folder: Path, first: tuple[str, ...]) -> list[Path]:
    pngs = sorted(folder.glob("*.png")) if folder.is_dir() else []
    rank = {n: i for i, n in enumerate(first)}
    return sorted(pngs, key=lambda p: (rank.get(p.stem, len(rank)), p.stem))


def _when(path: Path) -> str:
    # non-breaking hyphens and space: the date stays on one line in narrow table columns
    return _dt.datetime.fromtimestamp(path.stat().st_mtime).strftime("%Y\u2011%m\u2011%d\u00a0%H:%M")


class _Builder:
    """Builds the sections one by one from a ReportData."""

    def __init__(self, ws, video: bool, progress: bool):
        self.ws, self.d = ws, ReportData(ws)
        self.video, self.progress = video, progress
        self.out = ws.report_dir
        self.videos: list[str] = []
        self.reprojection: dict[str, dict[int, float]] = {}  # camera -> person -> median px (summary)

    def rel(self, p: Path) -> str:
        return p.relative_to(self.out).with_suffix("").as_posix()

    def say(self, msg: str) -> None:
        if self.progress:
            log.info(f"report: {msg}")

    # ---- overview ---------------------------------------------------------------------------
    def overview(self) -> Table:
        ws, d = self.ws, self.d
        first = lambda m: next(iter(m.values())) if m else None  # noqa: E731
        stages = [
            ("calibrate", ws.calibration, lambda: "calibration.toml",
             lambda: d.calibration and d.calibration[1].get("producer")),
            ("sync", ws.timing, lambda: "timing.toml",
             lambda: ws.timing.is_file() and read_toml(ws.timing, "timing file").get("producer")),
            ("track", ws.masks_dir, lambda: f"masks/ ({_n(len(d.mask_tracks), 'camera')})",
             lambda: d.mask_tracks and first(d.mask_tracks).producer),
            ("keypoints", ws.keypoints_dir, lambda: f"keypoints/ ({_n(len(d.keypoints), 'camera')})",
             lambda: d.keypoints and first(d.keypoints).producer),
            ("landmarks", ws.landmarks_dir,
             lambda: f"landmarks/ ({_n(len(d.landmarks), 'camera')}, source "
                     f"{', '.join(sorted({x.source for x in d.landmarks.values()})) or '?'})",
             lambda: d.landmarks and first(d.landmarks).producer),
            ("match", ws.identities, lambda: "identities.json", lambda: d.identities and d.identities.producer),
            ("fit", ws.smplx_dir, lambda: f"smplx/ ({_n(len(d.people), 'person')})",
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
                rows.append([stage, what(), "done", (prod() or {}).get("command") or "—", _when(path)])
            except UserError as e:
                rows.append([stage, path.name, f"unreadable: {e.message}", "—", _when(path)])
        return Table(["stage", "output", "status", "produced by", "written"], rows)

    # ---- 1. rig and calibration -------------------------------------------------------------
    def rig_section(self) -> Section:
        s = Section("rig", "Rig and calibration")
        d = self.d
        if d.calibration is None:
            s.missing("no calibration.toml", "mamma-kit calibrate WORKSPACE")
            return s
        rig, diag = d.calibration
        people = [(p.id, p.result.joints) for p in d.people]
        from mamma_kit.body import skeleton as sk
        from mamma_kit.report import figures

        self.say("rig figure")
        path = figures.rig_figure(rig, people, sk.PARENTS, self.out / "rig" / "rig3d.png")
        s.figure(self.rel(path), path, f"{len(rig)} cameras (frusta {', '.join(rig.names)})"
                 + (" and the fitted people: the middle frame's skeleton and the mean pelvis position; right: "
                    "pelvis paths on the floor" if people else "") + ". World frame: Z up, floor at z = 0.")
        if not people:
            s.missing("no fitted people to place in the rig", "mamma-kit fit WORKSPACE")
        rows = []
        for c in rig:
            cd = diag["cameras"].get(c.name, {})
            cv = cd.get("cross_validation_px") or {}
            rows.append([c.name, f"{c.width}x{c.height}", c.model, float(c.K[0, 0]), cd.get("rms_px"),
                         cd.get("intrinsics_rms_px"), cd.get("views"), cd.get("shared_views"),
                         cv.get("median_px"), cv.get("p95_px")])
        s.table(["camera", "size", "lens", "focal (px)", "rms (px)", "intrinsics rms (px)", "views",
                 "shared views", "cross-val. median (px)", "cross-val. p95 (px)"], rows, "cameras")
        r = diag["rig"]
        keys = [("rms_px", "bundle-adjusted rms (px)"), ("model", "lens model"), ("reference_camera", "reference"),
                ("timing", "board timing"), ("observations", "corner observations"), ("outliers", "outliers"),
                ("source", "source")]
        rig_rows = [[label, r[k]] for k, label in keys if k in r]
        if isinstance(r.get("world"), dict) and r["world"].get("source"):
            rig_rows.append(["world frame from", r["world"]["source"]])
        s.table(["rig", "value"], rig_rows, "rig")
        for w in r.get("warnings", []) or []:
            s.note(w, "warn")
        pngs = _ordered_pngs(self.out / "calibration", CALIB_ORDER)
        for p in pngs:
            s.figure(self.rel(p), p, _calib_caption(p.stem))
        if not pngs:
            s.missing("no calibration diagnostics pictures (report/calibration/; this calibration.toml was not "
                      "made from board videos here)", "mamma-kit calibrate WORKSPACE")
        return s

    # ---- 2. synchronisation -----------------------------------------------------------------
    def sync_section(self) -> Section:
        s = Section("sync", "Synchronisation")
        d = self.d
        if d.timing is None:
            s.missing("no timing.toml", "mamma-kit sync WORKSPACE")
            return s
        clocks, info = d.timing
        rows = []
        for n, clk in clocks.items():
            cd = info["cameras"].get(n, {})
            per = cd.get(clk.source, {}) if isinstance(cd.get(clk.source), dict) else {}
            rows.append([n, clk.offset * 1e3, clk.rate_ppm, clk.source, clk.confidence,
                         per.get("residual_rms_ms"), per.get("events")])
        s.table(["camera", "offset (ms)", "drift (ppm)", "method", "confidence", "residual rms (ms)", "events"],
                rows, f"clocks: t_ref = (1 + drift) t_cam + offset, reference {info.get('reference')}")
        dg = info.get("diagnostics", {})
        s.table(["sync", "value"], [[k, v] for k, v in (("method", info.get("method")),
                                                          ("methods tried", dg.get("methods_tried")),
                                                          ("methods that worked", dg.get("methods_ok")),
                                                          ("chosen", dg.get("chosen"))) if v is not None], "summary")
        pngs = _ordered_pngs(self.out / "sync", SYNC_ORDER)
        for p in pngs:
            s.figure(self.rel(p), p, _sync_caption(p.stem))
        if not pngs:
            s.missing("no sync pictures (report/sync/)", "mamma-kit sync WORKSPACE --force")
        return s

    # ---- 3. tracks and matching -------------------------------------------------------------
    def tracks_section(self) -> Section:
        s = Section("tracks", "Tracks and matching")
        d = self.d
        mt = d.mask_tracks
        if not mt:
            s.missing("no person tracks (masks/)", "mamma-kit track WORKSPACE")
        else:
            s.table(["camera", "tracks", "frames", "frames with a person", "track ids"],
                    [[c, len(m.track_ids), len(m.frame_times), int(m.present.any(1).sum()),
                      [int(t) for t in m.track_ids]] for c, m in mt.items()], "person tracks per view")
            for c in d.cameras:
                p = self.out / "tracks" / f"{c}.png"
                if p.is_file():
                    s.figure(self.rel(p), p, f"{c}: the frame with the most tracks, masks tinted by track id.")
        kp = d.keypoints
        if not kp:
            s.missing("no keypoints (keypoints/)", "mamma-kit keypoints WORKSPACE")
        else:
            s.table(["camera", "person-frames with keypoints", "tracked person-frames", "median pose score"],
                    [[c, int(k.valid.sum()), int(mt[c].present.sum()) if c in mt else "—",
                      f"{np.median(k.score[k.valid]):.2f}" if k.valid.any() else "—"] for c, k in kp.items()],
                    "BlazePose keypoints per view")
            for c in d.cameras:
                p = self.out / "keypoints" / f"{c}.png"
                if p.is_file():
                    s.figure(self.rel(p), p, f"{c}: BlazePose's points on frames spread over the capture, "
                                             "coloured by track (hollow: unlikely visible).")
        if d.identities is None:
            s.missing("no identities.json (which track shows which person)", "mamma-kit match WORKSPACE")
            return s
        ident = d.identities
        s.table(["person", "views", "tracks (camera:track, frames)"],
                [[p["id"], p["views"], ", ".join(f"{t['camera']}:{t['track']} ({t['frames']})" for t in p["tracks"])]
                 for p in ident.persons()], f"{_n(len(ident.person_ids), 'person')}, "
                                            f"{_n(len(ident.unassigned), 'unassigned track')}, "
                                            f"{_n(len(ident.rejected), 'rejected match', 'es')}")
        if ident.unassigned:
            s.table(["camera", "track", "why unassigned"],
                    [[u.get("camera"), u.get("track"), u.get("reason")] for u in ident.unassigned], "unassigned")
        p = self.out / "match" / "affinities.png"
        if p.is_file():
            s.figure(self.rel(p), p, "Track affinities across views (epipolar agreement of the landmarks), grouped "
                                     "by person; right: views per person.")
        else:
            s.missing("no matching picture (report/match/affinities.png)", "mamma-kit match WORKSPACE --force")
        return s

    # ---- 4. fit -----------------------------------------------------------------------------
    def fit_section(self) -> Section:
        s = Section("fit", "Fit")
        d = self.d
        if not d.people:
            s.missing("no fitted bodies (smplx/person_<k>.npz)", "mamma-kit fit WORKSPACE")
            return s
        rep = d.fit_report
        if rep:
            span = rep.get("time_span_s") or [None, None]
            s.table(["fit", "value"], [["body model", rep.get("body_model")], ["cameras", rep.get("cameras")],
                                       ["reference clock", rep.get("reference")], ["frames", rep.get("frames")],
                                       ["time span (s)", span], ["stages", rep.get("stages")],
                                       ["seconds", rep.get("seconds")], ["threads", rep.get("threads")]], "summary")
            st = rep.get("stage_stats", {})
            s.table(["stage", "wall (s)", "cpu (s)", "energy start", "energy end", "iterations"],
                    [[k, v.get("wall_s"), v.get("cpu_s"), v.get("energy_start"), v.get("energy_end"),
                      v.get("iterations")] for k, v in st.items()], "stages")
            s.table(["camera", "mean (px)", "median (px)", "p90 (px)", "landmarks"],
                    [[c, v.get("mean"), v.get("median"), v.get("p90"), v.get("landmarks")]
                     for c, v in rep.get("reprojection_px", {}).items()], "reprojection (fit_report.json)")
            s.table(["person", "frames observed", "file"],
                    [[p.get("id"), p.get("frames_observed"), p.get("file")] for p in rep.get("persons", [])], "people")
            for n in rep.get("notes", []) or []:
                s.note(n)
        else:
            s.missing("no smplx/fit_report.json", "mamma-kit fit WORKSPACE --force")
        if d.rig is None or not d.landmarks:
            s.missing("reprojection over time needs calibration.toml and landmarks/",
                      "mamma-kit calibrate / mamma-kit landmarks WORKSPACE")
            return s
        from mamma_kit.report import analysis, figures

        self.say("reprojection error over time")
        series, rows, notes = analysis.reprojection_over_time(d)
        if series:
            path = figures.reprojection_figure(series, d.cameras, self.out / "fit" / "reprojection_time.png")
            s.figure(self.rel(path), path,
                     "Per camera and person: the median distance (px) between the observed landmarks with visibility "
                     "> 0.5 and the fitted body's landmarks projected with calibration.toml, per frame. Each camera "
                     "frame's time is mapped to the reference clock with timing.toml; the body at that time is "
                     "interpolated linearly between the two nearest fitted frames. Dashed: the camera's median.")
            s.table(["camera", "person", "frames", "median (px)", "p90 (px)", "landmarks"], rows,
                    "reprojection over all frames")
            for cam, pid, _, med, _, _ in rows:
                self.reprojection.setdefault(cam, {})[pid] = round(med, 3)
        else:
            s.note("no camera sees a fitted person in its landmarks: nothing to compare")
        for n in notes:
            s.note(f"reprojection left out {n}", "warn")
        return s

    # ---- 5. contact -------------------------------------------------------------------------
    def contact_section(self) -> Section:
        s = Section("contact", "Contact")
        d = self.d
        if not d.landmarks:
            s.missing("no landmarks (landmarks/<cam>.npz)", "mamma-kit landmarks WORKSPACE")
            return s
        from mamma_kit.body import skeleton as sk
        from mamma_kit.report import analysis, figures

        self.say("contact figures")
        grid, contact = analysis.contact_over_time(d)
        if contact:
            path = figures.contact_time_figure(grid, contact, list(d.landmarks), self.out / "contact" / "over_time.png")
            s.figure(self.rel(path), path,
                     "Per person: the predicted probability that a landmark touches another person (left) or the "
                     "floor (right), averaged over the 512 landmarks; line: mean over the views seeing the person at "
                     "that reference time (nearest frame of each view), band: range over the views.")
        else:
            s.note("no track is matched to a person: no contact curves")
        c_l, f_l, n = analysis.contact_per_landmark(d)
        model = d.body_model
        if n and len(c_l) == len(model.landmark_ids):
            rest_l3 = model.np.v_template[model.landmark_ids]
            path = figures.contact_landmarks_figure(rest_l3, c_l, f_l, self.out / "contact" / "landmarks.png")
            s.figure(self.rel(path), path, f"Which landmarks are in contact most: the landmarks on the rest-pose "
                                           f"body coloured by their mean probability over {n} observations "
                                           f"(views x frames x matched tracks).")
            parts = model.landmark_parts
            for vals, label in ((f_l, "floor contact"), (c_l, "person contact")):
                top = [i for i in np.argsort(vals)[::-1][:8] if vals[i] >= MIN_CONTACT]
                s.table(["landmark", "part", "mean prob."],
                        [[int(i), sk.LANDMARK_PART_NAMES[int(parts[i])], float(vals[i])] for i in top],
                        f"most {label}")
                if not top:
                    s.note(f"no landmark has a mean {label} probability of {MIN_CONTACT:.0%} or more")
        elif n:
            s.note(f"the landmarks hold {len(c_l)} points, the body model {len(model.landmark_ids)}: no landmark map",
                   "warn")
        return s

    # ---- 6. overlays ------------------------------------------------------------------------
    def overlays_section(self) -> Section:
        s = Section("overlays", "Overlays")
        d = self.d
        if not d.people:
            s.missing("no fitted bodies to draw", "mamma-kit fit WORKSPACE")
            return s
        if d.rig is None:
            s.missing("no calibration.toml to project the bodies", "mamma-kit calibrate WORKSPACE")
            return s
        from mamma_kit.report import overlays

        cams, notes = overlays.overlay_cameras(d)
        for n in notes:
            s.note(f"no overlay for {n}", "warn")
        if not cams:
            s.missing("no camera video to draw on (capture.toml's videos)", "mamma-kit init WORKSPACE --videos ...")
            return s
        it = log.track(cams, "report: overlays") if self.progress else cams
        for c in it:
            res = overlays.overlay_stills(d, c, self.out / "overlays" / f"{c}.png")
            if res is None:
                s.note(f"{c}: no frame inside the fitted time span", "warn")
                continue
            path, times = res
            s.figure(self.rel(path), path,
                     f"{c}: the fitted meshes (one colour per person) over frames at reference times "
                     f"{', '.join(f'{t:.2f}' for t in times)} s; bodies interpolated between fitted frames.")
        if self.video:
            self.say("overlay video")
            path = self.out / "overlays" / "overlay.mp4"
            info = overlays.overlay_video(d, cams, path)
            self.videos.append(self.rel(path) + ".mp4")
            s.video(self.rel(path), path,
                    f"{', '.join(info['cameras'])}: {info['frames']} frames ({info['seconds']:.1f} s at "
                    f"{info['fps']:.0f} fps) from the start of the fitted span, "
                    f"{info['size'][0]}x{info['size'][1]} px.", width=info["size"][0])
        return s

    # ---- 7. ground truth --------------------------------------------------------------------
    def gt_section(self) -> Section | None:
        if not self.ws.gt_dir.is_dir():
            return None
        s = Section("gt", "Ground truth")
        from mamma_kit.evaluation import evaluate_workspace
        from mamma_kit.report import figures

        self.say("evaluation against ground truth")
        ev = evaluate_workspace(self.ws)
        if not ev:
            s.note("nothing to compare with the ground truth yet")
        for group, metrics in ev.items():
            for caption, cols, rows in _metric_tables(group, metrics):
                s.table(cols, rows, caption)
        people = (ev.get("fit") or {}).get("people") or []
        if any("mpjpe_mm" in p for p in people):
            path = figures.gt_fit_figure(people, self.out / "gt" / "mpjpe.png")
            s.figure(self.rel(path), path, "MPJPE (all 55 joints, body, hands), PA-MPJPE (after Procrustes "
                                           "alignment) and per-vertex error per person, in mm, against gt/.")
        return s


def _n(count: int, noun: str, plural: str = "s") -> str:
    return f"{count} {noun}{'' if count == 1 else plural}"


def _calib_caption(stem: str) -> str:
    if stem.startswith("camera_"):
        return (f"{stem[7:]}: board corner residuals over the image, per-view errors and coverage "
                f"(from `mamma-kit calibrate`).")
    return {"rig": "The calibrated rig with the board poses (from `mamma-kit calibrate`).",
            "connectivity": "Which cameras share still-board views, seen from above."}.get(stem, stem)


def _sync_caption(stem: str) -> str:
    return {"offsets": "Clock offset and drift per camera, with confidence.",
            "residuals": "Residuals of the clock fit per event.",
            "peaks": "Correlation peaks of the sync signal.",
            "agreement": "Agreement between sync methods."}.get(stem, stem)


def _metric_tables(group: str, metrics: dict) -> list[tuple[str, list[str], list[list]]]:
    """One evaluation group as tables: its scalars as name/value rows, every dict of dicts
    (e.g. per camera) and list of dicts (e.g. per person) as a table of its own."""
    out, scalars = [], []
    for k, v in metrics.items():
        if isinstance(v, dict) and v and all(isinstance(x, dict) for x in v.values()):
            cols = list(dict.fromkeys(c for x in v.values() for c in x))
            out.append((f"{group}: {k}", [k.rstrip("s") if k.endswith("s") else k] + cols,
                        [[name] + [x.get(c) for c in cols] for name, x in v.items()]))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            cols = list(dict.fromkeys(c for x in v for c in x))
            out.append((f"{group}: {k}", cols, [[x.get(c) for c in cols] for x in v]))
        elif isinstance(v, dict):  # a few named numbers: one row each
            scalars += [[f"{k}.{kk}", x] for kk, x in v.items()]
        else:
            scalars.append([k, v])
    if scalars:
        out.insert(0, (group, ["metric", "value"], scalars))
    return out


def _nothing_to_report(ws) -> bool:
    return not (ws.calibration.is_file() or ws.timing.is_file() or any(ws.masks_dir.glob("*.npz"))
                or any(ws.landmarks_dir.glob("*.npz")) or ws.identities.is_file() or ws.person_files())


def build_report(ws, *, video: bool = True, rerun: bool = False, progress: bool = True) -> dict:
    """Write ws.report_dir / 'index.html'; return a JSON-able summary: {"path": str, "figures": [names],
    "sections": [...], "seconds": float, ...}."""
    t0 = time.perf_counter()
    if _nothing_to_report(ws):
        raise UserError(f"nothing to report in {ws.root}: no calibration.toml, timing.toml, masks/, landmarks/, "
                        "identities.json or smplx/",
                        "run the stages first: `mamma-kit capture-to-smplx WORKSPACE` runs them all")
    if rerun:
        from mamma_kit.report.rerun_export import require_rerun

        require_rerun()  # fail before the long work
    b = _Builder(ws, video, progress)
    sections = []
    for make in (b.rig_section, b.sync_section, b.tracks_section, b.fit_section, b.contact_section,
                 b.overlays_section, b.gt_section):
        try:
            s = make()
        except UserError as e:  # an unreadable input spoils its section, not the report
            s = Section(make.__name__.removesuffix("_section"), make.__name__.removesuffix("_section").title())
            s.note(f"could not build this section: {e.line()}", "warn")
        if s is not None:
            sections.append(s)
    overview = b.overview()
    notes = b.d.notes
    d = b.d
    sub = (f"{ws.root} · {_n(len(d.cameras), 'camera')} · {len(d.people)} fitted "
           f"{'person' if len(d.people) == 1 else 'people'}"
           + (" · synthetic (ground truth in gt/)" if ws.gt_dir.is_dir() else ""))
    stamp = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    page = render_page(f"mamma-kit report: {d.name}", sub, overview, sections,
                       f"written {stamp} by mamma-kit {__version__}" + (" · " + "; ".join(notes) if notes else ""))
    path = atomic_write_text(ws.report_dir / "index.html", page)
    rrd = None
    if rerun:
        from mamma_kit.report.rerun_export import write_recording

        b.say("rerun recording")
        rrd = ws.relative(write_recording(d, ws.report_dir / "recording.rrd"))
    figures = [f.name for s in sections for f in s.figures]
    return {
        "stage": "report", "path": str(path), "figures": figures,
        "sections": [s.id for s in sections if s.has_content],
        "missing": [f"{s.id}: {m}" for s in sections for m in s.missing_lines],
        "videos": b.videos, "rerun": rrd, "reprojection_median_px": b.reprojection, "bytes": path.stat().st_size,
        "seconds": round(time.perf_counter() - t0, 2),
    }


def report_inputs(ws) -> list[Path]:
    """Every file the report reads: the stages' outputs and pictures, and gt/ when present."""
    root = ws.root
    files = [ws.capture_toml, ws.calibration, ws.timing, ws.identities]
    for pattern in ("masks/*.npz", "landmarks/*.npz", "smplx/*.npz", "smplx/*.json", "report/calibration/*.png",
                    "report/sync/*.png", "report/tracks/*.png", "keypoints/*.npz", "report/keypoints/*.png", "report/match/*.png", "gt/**/*.npz", "gt/*.toml"):
        files += sorted(root.glob(pattern))
    return [p for p in files if p.is_file()]


def run_report(ws, *, video: bool = True, force: bool = False, progress: bool = True) -> dict:
    """The report as a pipeline stage: rebuilt only when something it shows changed
    (manifest .cache/report.json)."""
    from mamma_kit.core.manifest import StageManifest

    inputs = report_inputs(ws)
    manifest = StageManifest(ws.cache_dir, "report", ws.root)
    key = {"video": video}
    index = ws.report_dir / "index.html"
    state = manifest.check(inputs, key)
    if state.fresh and not force and index.is_file():
        log.info(f"report: up to date ({state.reason}); skipped")
        return {"stage": "report", "skipped": True, "reason": state.reason, "path": str(index)}
    res = build_report(ws, video=video, progress=progress)
    manifest.record(inputs, key, [index], {"path": res["path"]}, res.get("seconds"))
    return {"stage": "report", "skipped": False, "reason": state.reason, **res}
