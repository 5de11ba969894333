"""``build_report(ws)``: the report page, section by section (report/__init__.py lists them).

Each section method of ``_Builder`` reads what it needs from one ``ReportData``, draws its new
figures (figures.py, overlays.py), takes its tables and captions from tables.py and names what
is missing with the command that makes it.
"""

from __future__ import annotations

import datetime as _dt
import time

import numpy as np

from mamma_kit import __version__
from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import atomic_write_text
from mamma_kit.report.data import ReportData
from mamma_kit.report.html import Section, render_page
from mamma_kit.report.tables import (AFFINITIES_CAPTION, CALIB_ORDER, CONTACT_TIME_CAPTION, GT_CAPTION,
                                     REPROJECTION_CAPTION, SYNC_ORDER, calib_caption, calibration_tables, checks_table,
                                     contact_landmarks_caption, fit_report_tables, identity_tables, keypoint_table,
                                     metric_tables, n_of, ordered_pngs, overlay_caption, overlay_video_caption,
                                     overview_table, rig_caption, sync_caption, sync_tables, track_table)

MIN_CONTACT = 0.01  # landmarks below this mean probability are not listed as "most in contact"


class _Builder:
    """Builds the sections one by one from a ReportData."""

    def __init__(self, ws, video: bool, progress: bool):
        self.ws, self.d = ws, ReportData(ws)
        self.video, self.progress = video, progress
        self.out = ws.report_dir
        self.videos: list[str] = []
        self.reprojection: dict[str, dict[int, float]] = {}  # camera -> person -> median px (summary)

    def rel(self, p) -> str:
        return p.relative_to(self.out).with_suffix("").as_posix()

    def say(self, msg: str) -> None:
        if self.progress:
            log.info(f"report: {msg}")

    def add_pngs(self, s: Section, folder: str, order: tuple[str, ...], caption) -> bool:
        """The pictures another command left in report/<folder>/, in ``order``; False if none."""
        pngs = ordered_pngs(self.out / folder, order)
        for p in pngs:
            s.figure(self.rel(p), p, caption(p.stem))
        return bool(pngs)

    def add_camera_pngs(self, s: Section, folder: str, caption) -> None:
        """report/<folder>/<camera>.png for each camera that has one; ``caption(camera)``."""
        for c in self.d.cameras:
            p = self.out / folder / f"{c}.png"
            if p.is_file():
                s.figure(self.rel(p), p, caption(c))

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
        s.figure(self.rel(path), path, rig_caption(rig.names, bool(people)))
        if not people:
            s.missing("no fitted people to place in the rig", "mamma-kit fit WORKSPACE")
        for t in calibration_tables(rig, diag):
            s.table(*t)
        for w in diag["rig"].get("warnings", []) or []:
            s.note(w, "warn")
        if not self.add_pngs(s, "calibration", CALIB_ORDER, calib_caption):
            s.missing("no calibration diagnostics pictures (report/calibration/; this calibration.toml was not "
                      "made from board videos here)", "mamma-kit calibrate WORKSPACE")
        return s

    # ---- 2. synchronisation -----------------------------------------------------------------
    def sync_section(self) -> Section:
        s = Section("sync", "Synchronisation")
        if self.d.timing is None:
            s.missing("no timing.toml", "mamma-kit sync WORKSPACE")
            return s
        for t in sync_tables(*self.d.timing):
            s.table(*t)
        if not self.add_pngs(s, "sync", SYNC_ORDER, sync_caption):
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
            s.table(*track_table(mt))
            self.add_camera_pngs(s, "tracks", lambda c: f"{c}: the frame with the most tracks, masks tinted by "
                                                        "track id.")
        kp = d.keypoints
        if not kp:
            s.missing("no keypoints (keypoints/)", "mamma-kit keypoints WORKSPACE")
        else:
            s.table(*keypoint_table(kp, mt))
            self.add_camera_pngs(s, "keypoints", lambda c: f"{c}: BlazePose's points on frames spread over the "
                                                           "capture, coloured by track (hollow: unlikely visible).")
        if d.identities is None:
            s.missing("no identities.json (which track shows which person)", "mamma-kit match WORKSPACE")
            return s
        for t in identity_tables(d.identities):
            s.table(*t)
        self.add_camera_pngs(s, "match", lambda c: f"{c}: who is who in one frame: tracks tinted by person (P0, "
                                                   "P1, ...), tracks set aside outlined in grey with the reason.")
        self.add_camera_pngs(s, "place", lambda c: f"{c}: the frame with the most people placed from the fitted "
                                                   "bodies (`mamma-kit place`): their visible silhouettes, labelled "
                                                   "'placed', beside the view's own tracks.")
        p = self.out / "match" / "affinities.png"
        if p.is_file():
            s.figure(self.rel(p), p, AFFINITIES_CAPTION)
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
            for t in fit_report_tables(rep):
                s.table(*t)
            for n in rep.get("notes", []) or []:
                s.note(n)
            if rep.get("checks"):
                table, verdict = checks_table(rep["checks"])
                s.note(verdict, "info" if rep["checks"]["passed"] else "warn")
                if table:
                    s.table(*table)
        else:
            s.missing("no smplx/fit_report.json", "mamma-kit fit WORKSPACE --force")
        if d.rig is None or not d.landmarks:
            s.missing("reprojection over time needs calibration.toml and landmarks/",
                      "mamma-kit calibrate / mamma-kit landmarks WORKSPACE")
            return s
        self.add_reprojection(s)
        return s

    def add_reprojection(self, s: Section) -> None:
        """The reprojection error per camera and person over time; its medians go to the summary."""
        from mamma_kit.report import analysis, figures

        self.say("reprojection error over time")
        series, rows, notes = analysis.reprojection_over_time(self.d)
        if series:
            path = figures.reprojection_figure(series, self.d.cameras, self.out / "fit" / "reprojection_time.png")
            s.figure(self.rel(path), path, REPROJECTION_CAPTION)
            s.table(["camera", "person", "frames", "median (px)", "p90 (px)", "landmarks"], rows,
                    "reprojection over all frames")
            for cam, pid, _, med, _, _ in rows:
                self.reprojection.setdefault(cam, {})[pid] = round(med, 3)
        else:
            s.note("no camera sees a fitted person in its landmarks: nothing to compare")
        for n in notes:
            s.note(f"reprojection left out {n}", "warn")

    # ---- 5. contact -------------------------------------------------------------------------
    def contact_section(self) -> Section:
        s = Section("contact", "Contact")
        d = self.d
        if not d.landmarks:
            s.missing("no landmarks (landmarks/<cam>.npz)", "mamma-kit landmarks WORKSPACE")
            return s
        from mamma_kit.report import analysis, figures

        self.say("contact figures")
        grid, contact = analysis.contact_over_time(d)
        if contact:
            path = figures.contact_time_figure(grid, contact, list(d.landmarks), self.out / "contact" / "over_time.png")
            s.figure(self.rel(path), path, CONTACT_TIME_CAPTION)
        else:
            s.note("no track is matched to a person: no contact curves")
        c_l, f_l, n = analysis.contact_per_landmark(d)
        model = d.body_model
        if n and len(c_l) == len(model.landmark_ids):
            self.add_contact_landmarks(s, c_l, f_l, n)
        elif n:
            s.note(f"the landmarks hold {len(c_l)} points, the body model {len(model.landmark_ids)}: no landmark map",
                   "warn")
        return s

    def add_contact_landmarks(self, s: Section, c_l: np.ndarray, f_l: np.ndarray, n: int) -> None:
        """The (L,) mean person- and floor-contact probabilities on the rest-pose body, and the
        landmarks most in contact of each kind."""
        from mamma_kit.body import skeleton as sk
        from mamma_kit.report import figures

        model = self.d.body_model
        rest_l3 = model.np.v_template[model.landmark_ids]
        path = figures.contact_landmarks_figure(rest_l3, c_l, f_l, self.out / "contact" / "landmarks.png")
        s.figure(self.rel(path), path, contact_landmarks_caption(n))
        parts = model.landmark_parts
        for vals, label in ((f_l, "floor contact"), (c_l, "person contact")):
            top = [i for i in np.argsort(vals)[::-1][:8] if vals[i] >= MIN_CONTACT]
            s.table(["landmark", "part", "mean prob."],
                    [[int(i), sk.LANDMARK_PART_NAMES[int(parts[i])], float(vals[i])] for i in top],
                    f"most {label}")
            if not top:
                s.note(f"no landmark has a mean {label} probability of {MIN_CONTACT:.0%} or more")

    # ---- 6. overlays ------------------------------------------------------------------------
    def view3d_section(self) -> Section:
        s = Section("view3d", "3D view")
        d = self.d
        if not d.people:
            s.missing("no fitted bodies to show", "mamma-kit fit WORKSPACE")
            return s
        from mamma_kit.core.colour import person_colour
        from mamma_kit.report import view3d

        self.say("3D view")
        people = [(p.id, p.result) for p in d.people]
        html_text, caption = view3d.viewer_html(people, d.body_model, d.rig, {k: person_colour(k) for k, _ in people})
        if html_text is None:
            s.note(caption, "missing")
        else:
            s.embed("view3d", html_text, caption)
        return s

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
            s.figure(self.rel(path), path, overlay_caption(c, times))
        if self.video:
            self.say("overlay video")
            path = self.out / "overlays" / "overlay.mp4"
            info = overlays.overlay_video(d, cams, path)
            self.videos.append(self.rel(path) + ".mp4")
            s.video(self.rel(path), path, overlay_video_caption(info), width=info["size"][0])
        return s

    # ---- 7. ground truth --------------------------------------------------------------------
    def gt_section(self) -> Section | None:
        if not self.ws.gt_dir.is_dir():
            return None
        s = Section("gt", "Ground truth")
        from mamma_kit.evaluation.stage import evaluate_workspace
        from mamma_kit.report import figures

        self.say("evaluation against ground truth")
        ev = evaluate_workspace(self.ws)
        if not ev:
            s.note("nothing to compare with the ground truth yet")
        for group, metrics in ev.items():
            for t in metric_tables(group, metrics):
                s.table(*t)
        people = (ev.get("fit") or {}).get("people") or []
        if any("mpjpe_mm" in p for p in people):
            path = figures.gt_fit_figure(people, self.out / "gt" / "mpjpe.png")
            s.figure(self.rel(path), path, GT_CAPTION)
        return s


def build_sections(b: _Builder) -> list[Section]:
    """Every section whose inputs exist, in order; an unreadable input spoils its section only."""
    out = []
    for make in (b.rig_section, b.sync_section, b.tracks_section, b.fit_section, b.view3d_section,
                 b.contact_section, b.overlays_section, b.gt_section):
        try:
            s = make()
        except UserError as e:
            s = Section(make.__name__.removesuffix("_section"), make.__name__.removesuffix("_section").title())
            s.note(f"could not build this section: {e.line()}", "warn")
        if s is not None:
            out.append(s)
    return out


def nothing_to_report(ws) -> bool:
    return not (ws.calibration.is_file() or ws.timing.is_file() or any(ws.masks_dir.glob("*.npz"))
                or any(ws.landmarks_dir.glob("*.npz")) or ws.identities.is_file() or ws.person_files())


def build_report(ws, *, video: bool = True, rerun: bool = False, progress: bool = True) -> dict:
    """Write ws.report_dir / 'index.html'; return a JSON-able summary: {"path": str, "figures": [names],
    "sections": [...], "seconds": float, ...}."""
    t0 = time.perf_counter()
    if nothing_to_report(ws):
        raise UserError(f"nothing to report in {ws.root}: no calibration.toml, timing.toml, masks/, landmarks/, "
                        "identities.json or smplx/",
                        "run the stages first: `mamma-kit capture-to-smplx WORKSPACE` runs them all")
    if rerun:
        from mamma_kit.report.rerun_export import require_rerun

        require_rerun()  # fail before the long work
    b = _Builder(ws, video, progress)
    sections = build_sections(b)
    d = b.d
    overview = overview_table(ws, d)
    notes = d.notes
    sub = (f"{ws.root} · {n_of(len(d.cameras), 'camera')} · {len(d.people)} fitted "
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
    return {
        "stage": "report", "path": str(path), "figures": [f.name for s in sections for f in s.figures],
        "sections": [s.id for s in sections if s.has_content],
        "missing": [f"{s.id}: {m}" for s in sections for m in s.missing_lines],
        "videos": b.videos, "rerun": rrd, "reprojection_median_px": b.reprojection, "bytes": path.stat().st_size,
        "seconds": round(time.perf_counter() - t0, 2),
    }
