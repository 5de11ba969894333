"""capture-to-smplx: the whole chain on one workspace, each stage cached by its inputs.

    calibrate -> sync -> track -> keypoints -> landmarks -> match -> fill -> fit -> place -> export -> report

(sync runs after track and keypoints when its method is motion or auto: motion sync reads the
people's keypoints.)

Every stage is the same function its own command calls (calibration.stage, timing.stage,
masks.stage, landmarks.stage, matching.stage, fitting.stage, export.stage, report.stage),
so a stage is skipped exactly when its manifest (.cache/<stage>.json, per camera for track
and landmarks) says its inputs, settings and outputs are unchanged, and recomputed - saying
why - when anything it reads changed. Outputs are written atomically and a manifest only
after its outputs, so a run killed at any point resumes where it stopped: finished stages
(and cameras) are reused, the interrupted one is redone.

Stage options come from capture.toml, e.g.::

    [settings.calibrate]   model = "radtan"   detect_fps = 10   max_views = 40   floor = true
                           people = false   (after match, the poses of cameras the people show to be
                           off are refined from them and the match runs again; default "auto")
    [settings.sync]        method = "auto"    (and every sync setting; see sync/*.toml)
    [settings.track]       backend = "builtin"   (sam2: sam2_checkpoint, sam2_config, chunk, device)
    [settings.keypoints]   resplit = false | 3   (rounds of touching people read again on masks re-split by their points)
                           hands = false   (each person's hands read by the hand model too; default true)
    [settings.landmarks]   weights = "..."  arch = "embedded"  batch = 8  hands = "off"   (source = "gt" on synthetic data)
                           smooth_s = 0   (contact and visibility smoothing over time, s; default 0.1)
                           contact = "off"   (the body network's own contact head; default "auto": the single-query network's)
    [settings.match]       lam = 0.05  max_distance = 0.12  min_affinity = 0.25  window = 2.0
    [settings.fit]         stages = 4  cameras = 4 | camera_list = ["cam0", ...]  chunk = 120  floor = false
                           hand_points = false   (the hand model's points in the fit; default true)
    [settings.place]       enabled = false   (the fitted bodies placed in the views that lost them; default true)
    [settings.export]      formats = ["gltf", "bvh", "trc", "c3d", "amass"]   (default ["gltf"]; [] writes none)
    [settings.report]      video = true
    [settings]             executor = "ray"   ray_address = "HOST:6379"   (core/executor.py; default local)

``init_workspace`` (`mamma-kit init`) writes that capture.toml for a user's own videos.
"""

from __future__ import annotations

import os
import re
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.workspace import STAGES, Workspace

KNOWN = {
    "calibrate": {"model", "detect_fps", "max_views", "floor", "board", "people"},
    "track": {"backend", "sam2_checkpoint", "sam2_config", "chunk", "device", "prompts", "pictures", "people"},
    "keypoints": {"blank", "threads", "pictures", "resplit", "hands"},
    "landmarks": {"source", "weights", "arch", "batch", "device", "noise", "outliers", "seed", "threads", "hands",
                  "smooth_s", "contact"},
    "match": {"lam", "max_distance", "min_affinity", "window", "plots"},
    "fill": {"enabled"},
    "fit": {"stages", "cameras", "camera_list", "chunk", "floor", "threads", "body_model", "hand_points"},
    "place": {"enabled"},
    "export": {"formats"},
    "report": {"video"},
}


@dataclass
class RunSummary:
    workspace: str
    stages: dict[str, dict] = field(default_factory=dict)
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return {"workspace": self.workspace, "stages": self.stages, "seconds": round(self.seconds, 2),
                "ran": [s for s, d in self.stages.items() if d.get("status") == "ran"],
                "skipped": [s for s, d in self.stages.items() if d.get("status") == "skipped"]}


def _options(cap, stage: str) -> dict:
    opts = cap.stage_settings(stage)
    if stage in KNOWN:
        bad = sorted(set(opts) - KNOWN[stage])
        if bad:
            raise UserError(f"capture.toml [settings.{stage}] has unknown keys: {', '.join(bad)}",
                            f"valid keys: {', '.join(sorted(KNOWN[stage]))}")
    return opts


def stage_range(from_stage: str | None, to_stage: str | None) -> list[str]:
    for s in (from_stage, to_stage):
        if s is not None and s not in STAGES:
            raise UserError(f"unknown stage '{s}'", f"stages: {', '.join(STAGES)}")
    a = STAGES.index(from_stage) if from_stage else 0
    b = STAGES.index(to_stage) if to_stage else len(STAGES) - 1
    if a > b:
        raise UserError(f"--from {from_stage} comes after --to {to_stage}", f"stages run in order: {' -> '.join(STAGES)}")
    return list(STAGES[a:b + 1])


def _key_facts(stage: str, res: dict) -> str:
    """One line of the stage's key diagnostics for the summary."""
    try:
        if stage == "calibrate":
            return f"rms {res['rms_px']:.3f} px" if res.get("rms_px") is not None else res.get("note", "")
        if stage == "sync":
            cams = res.get("cameras", {})
            return ", ".join(f"{n} {c['offset_s'] * 1e3:+.2f} ms ({c['method']}, conf {c['confidence']:.2f})"
                             for n, c in cams.items())
        if stage == "track":
            return ", ".join(f"{c['camera']} {c.get('tracks', '?')} tracks" for c in res.get("cameras", []))
        if stage == "keypoints":
            return ", ".join(f"{c['camera']} {c.get('with_pose', '?')}/{c.get('instances', '?')} person-frames"
                             for c in res.get("cameras", []))
        if stage == "landmarks":
            return f"{res.get('source')} {res.get('arch', '')}".strip()
        if stage == "match":
            persons = res.get("persons") or []
            refined = (res.get("poses") or {}).get("refined") or []
            return (f"{len(persons)} person(s), views " + ", ".join(str(p.get("views")) for p in persons)
                    + (f"; camera poses refined from the people: {', '.join(refined)}" if refined else ""))
        if stage == "fill":
            return (f"{res.get('found', 0)} of {res.get('gaps', 0)} missing person-view-frames found"
                    if "found" in res else str(res.get("reason", "")))
        if stage == "place":
            return (f"{res.get('placed', 0)} hidden person-view-frames placed in {res.get('tracks', 0)} tracks, "
                    f"{res.get('relabelled', 0)} track-frames given the person they show"
                    if "placed" in res else str(res.get("reason", "")))
        if stage == "fit":
            rp = res.get("reprojection_px", {})
            med = [v["median"] for v in rp.values() if v.get("landmarks")]
            ch = res.get("checks") or {}
            checks = ("" if not ch else "; physical checks passed" if ch["passed"] and not ch["flags"] else
                      f"; physical checks: {ch['impossible_frames']} impossible, {ch['doubtful_frames']} doubtful "
                      "person-frames")
            return (f"{len(res.get('persons', []))} person(s) x {res.get('frames')} frames, median reprojection "
                    f"{sum(med) / len(med):.2f} px" + checks if med else "")
        if stage == "export":
            return ", ".join(Path(f["path"]).name for f in res.get("files", []))
        if stage == "report":
            return str(res.get("path", ""))
    except (KeyError, TypeError, ZeroDivisionError):
        return ""
    return ""


def _written_by_sync(timing: Path) -> bool:
    """Whether timing.toml is mamma-kit sync's own output (else the user gave it: keep it)."""
    from mamma_kit.core.io import read_toml

    command = str((read_toml(timing, "timing file").get("producer") or {}).get("command", ""))
    return command.startswith("sync")


def run_stage(ws: Workspace, stage: str, cap, force: bool = False, progress: bool = True) -> dict:
    """Run (or skip) one stage with capture.toml's options; returns its summary with 'status'."""
    opts = _options(cap, stage)
    if stage == "calibrate":
        has_board = any(e.board_video is not None for e in cap.cameras.values())
        if not has_board:
            if ws.calibration.is_file():
                return {"stage": "calibrate", "status": "provided",
                        "note": "calibration.toml given (no board videos in capture.toml)"}
            raise UserError("no calibration: capture.toml lists no board videos and there is no calibration.toml",
                            "add board_video = \"...\" per camera (and [board] spec), or put a calibration.toml "
                            "in the workspace (`mamma-kit calib convert` reads other tools' formats)")
        from mamma_kit.calibration.stage import run_calibrate, settings_from

        st = settings_from(opts.get("model", "radtan"), float(opts.get("detect_fps", 10.0)),
                           int(opts.get("max_views", 40)), bool(opts.get("floor", True)))
        res = run_calibrate(ws, board=opts.get("board"), settings=st, force=force, progress=progress)
    elif stage == "sync":
        from mamma_kit.timing.stage import run_sync

        if ws.timing.is_file() and not force and not _written_by_sync(ws.timing):
            return {"stage": "sync", "status": "provided",
                    "note": "timing.toml given (not written by `mamma-kit sync`); --force recomputes it"}
        res = run_sync(ws, force=force)
    elif stage == "track":
        from mamma_kit.masks.stage import run_track

        res = run_track(ws, backend=opts.get("backend", "builtin"),
                        sam2_checkpoint=ws.resolve(opts["sam2_checkpoint"], "sam2 checkpoint")
                        if opts.get("sam2_checkpoint") else None, sam2_config=opts.get("sam2_config"),
                        chunk=int(opts.get("chunk", 64)), device=opts.get("device", "cpu"),
                        prompts=ws.resolve(opts["prompts"], "prompts file") if opts.get("prompts") else None,
                        pictures=bool(opts.get("pictures", True)), force=force, people=opts.get("people"))
    elif stage == "keypoints":
        from mamma_kit.keypoints.stage import run_keypoints

        res = run_keypoints(ws, blank=bool(opts.get("blank", True)), pictures=bool(opts.get("pictures", True)),
                            force=force, threads=opts.get("threads"), unit_frames=opts.get("unit_frames"),
                            resplit=opts.get("resplit", True), hands=bool(opts.get("hands", True)))
    elif stage == "landmarks":
        from mamma_kit.landmarks.stage import run_landmarks

        if "threads" in opts:
            log.warn("capture.toml [settings.landmarks] threads no longer applies: the network's units run on "
                     "one thread each, side by side (mamma-kit --workers N sets how many)")
        res = run_landmarks(ws, source=opts.get("source", "net"), weights=opts.get("weights"), arch=opts.get("arch"),
                            batch=int(opts.get("batch", 8)), device=opts.get("device", "cpu"),
                            noise=str(opts.get("noise", "0")), outliers=float(opts.get("outliers", 0.0)),
                            seed=int(opts.get("seed", 0)), force=force, unit_frames=opts.get("unit_frames"),
                            hands=opts.get("hands", "auto"), smooth_s=opts.get("smooth_s"),
                            contact=opts.get("contact", "auto"))
    elif stage == "match":
        from mamma_kit.matching.stage import run_match

        def match(force: bool = force) -> dict:
            return run_match(ws, lam=float(opts.get("lam", 0.05)), max_distance=float(opts.get("max_distance", 0.12)),
                             min_affinity=float(opts.get("min_affinity", 0.25)), window_s=float(opts.get("window", 2.0)),
                             plots=bool(opts.get("plots", True)), force=force)

        res = match()
        if _options(cap, "calibrate").get("people", "auto") is not False:  # people = false in capture.toml
            # the camera poses the matched people show to be off are refined (calibration/people.py;
            # nothing changes where no camera stands out), and the people matched again on them
            from mamma_kit.calibration.people import refine_if_off

            again = {}
            poses = refine_if_off(ws, rematch=lambda: again.update(match(force=True)), force=force)
            res = {**(again or res), "poses": poses}
    elif stage == "fill":
        from mamma_kit.filling.stage import run_fill

        res = run_fill(ws, force=force, enabled=bool(opts.get("enabled", True)))
    elif stage == "fit":
        from mamma_kit.fitting.stage import fit_workspace
        from mamma_kit.fitting.stages import FitConfig

        cfg = FitConfig(chunk=int(opts.get("chunk", 120)), floor=bool(opts.get("floor", False)))
        if not opts.get("hand_points", True):
            cfg.hand_keypoint_weight = 0.0
        res = fit_workspace(ws, opts.get("cameras"), opts.get("camera_list"), int(opts.get("stages", 4)),
                            opts.get("body_model"), cfg, command="mamma-kit capture-to-smplx", force=force,
                            threads=opts.get("threads"))
    elif stage == "place":
        from mamma_kit.placing.stage import run_place

        res = run_place(ws, force=force, enabled=bool(opts.get("enabled", True)))
    elif stage == "export":
        from mamma_kit.export.stage import DEFAULT_FORMATS, run_export

        res = run_export(ws, formats=opts.get("formats", DEFAULT_FORMATS), force=force)
    elif stage == "report":
        from mamma_kit.report.stage import run_report

        res = run_report(ws, video=bool(opts.get("video", True)), force=force, progress=progress)
    else:  # pragma: no cover - stage_range guards this
        raise ValueError(stage)
    res = dict(res)
    res["status"] = "skipped" if res.get("skipped") else "ran"
    return res


def capture_to_smplx(workspace: str | Path, from_stage: str | None = None, to_stage: str | None = None,
                     force: bool = False, progress: bool = True) -> dict:
    """Run the chain on a workspace; returns the run summary (per stage: status, seconds, reason,
    key facts, and the stage's own summary)."""
    from mamma_kit.core.reproducible import configure

    configure()  # same inputs and settings, same numbers (core/reproducible.py)
    ws = Workspace(workspace)
    cap = ws.load_capture()
    stages = stage_range(from_stage, to_stage)
    if str(cap.stage_settings("sync").get("method", "auto")) in ("motion", "auto") and {"sync", "keypoints"} <= set(stages):
        # motion sync reads the people's keypoints (auto tries it too): sync runs after them; tracking
        # and keypoints do not read the clocks
        stages.remove("sync")
        stages.insert(stages.index("keypoints") + 1, "sync")
    run = RunSummary(str(ws.root))
    t0 = time.perf_counter()
    from mamma_kit.core.executor import executor_for_run

    # [settings] executor = "ray" (and ray_address) runs the stages' units on Ray, unless
    # --executor or MAMMA_KIT_EXECUTOR chose already
    with executor_for_run(cap.settings):
        for i, stage in enumerate(stages):
            log.info(f"[bold]\\[{i + 1}/{len(stages)}] {stage}[/bold]")
            ts = time.perf_counter()
            res = run_stage(ws, stage, cap, force=force, progress=progress)
            secs = time.perf_counter() - ts
            facts = _key_facts(stage, res)
            run.stages[stage] = {"status": res["status"], "seconds": round(secs, 2), "reason": res.get("reason", ""),
                                 "facts": facts, "summary": res}
            log.info(f"    {stage}: {res['status']} in {secs:.1f} s" + (f" - {facts}" if facts else ""))
    run.seconds = time.perf_counter() - t0
    out = run.to_dict()
    fit = run.stages.get("fit", {}).get("summary", {})
    if fit.get("checks"):
        out["checks"] = {k: fit["checks"][k] for k in ("passed", "impossible_frames", "doubtful_frames", "by_check")}
    return out


def print_summary(summary: dict) -> None:
    """A table of what ran, how long, and the key diagnostics (stderr)."""
    from rich.table import Table

    t = Table(title=f"capture-to-smplx: {summary['workspace']}", show_lines=False)
    for col in ("stage", "status", "seconds", "key diagnostics"):
        t.add_column(col)
    for name, d in summary["stages"].items():
        t.add_row(name, d["status"], f"{d['seconds']:.1f}", d.get("facts", ""))
    t.add_row("total", "", f"{summary['seconds']:.1f}", "")
    if not log.is_quiet():
        log.console.print(t)
    fit = summary["stages"].get("fit", {}).get("summary", {})
    if fit.get("skipped") and fit.get("checks") and fit["checks"]["flags"]:  # a fit that ran said them already
        from mamma_kit.fitting.checks import summary_lines

        for line in summary_lines(fit["checks"]):
            log.warn(f"fit check: {line}")


# ---- mamma-kit init ---------------------------------------------------------------------
NAME_RE = re.compile(r"^[A-Za-z0-9_.-]+$")


def _place(src: Path, dst: Path, copy: bool) -> str:
    """Hard link (else copy) src to dst; returns 'linked' / 'copied' / 'kept'."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists():
        if dst.samefile(src):
            return "kept"
        dst.unlink()
    if not copy:
        try:
            os.link(src, dst)
            return "linked"
        except OSError:  # another filesystem: copy instead
            pass
    shutil.copy2(src, dst)
    return "copied"


def init_workspace(root: str | Path, videos: list[Path], board_videos: list[Path] | None = None,
                   board: str | None = None, names: list[str] | None = None, copy: bool = False,
                   backend: str = "pose", force: bool = False, people: int | None = None,
                   calibration: str | Path | None = None, synced: bool = False) -> dict:
    """A capture workspace for a user's own videos: they are hard-linked (or copied) into
    WORKSPACE/videos and WORKSPACE/board, so that capture.toml holds only paths inside the
    workspace, and each is checked to be a readable video before anything is written.
    ``calibration`` (any format calib convert reads) is written as WORKSPACE/calibration.toml
    instead of calibrating from board videos."""
    from mamma_kit.video import VideoReader

    ws = Workspace(root, must_exist=False)
    if ws.capture_toml.is_file() and not force:
        raise UserError(f"{ws.capture_toml} already exists", "pass --force to overwrite it, or choose another folder")
    videos = [Path(v) for v in videos]
    if len(videos) < 2:
        raise UserError("a capture needs videos from at least two cameras", "pass --videos A.mp4 B.mp4 ...")
    names = names or [v.stem for v in videos]
    if len(names) != len(videos):
        raise UserError(f"{len(names)} names for {len(videos)} videos", "give one --names entry per video")
    if len(set(names)) != len(names):
        raise UserError(f"camera names repeat: {', '.join(names)}", "rename the files or pass --names cam0,cam1,...")
    bad = [n for n in names if not NAME_RE.match(n)]
    if bad:
        raise UserError(f"camera names with spaces or symbols: {', '.join(bad)}", "pass --names cam0,cam1,...")
    if board_videos:
        board_videos = [Path(v) for v in board_videos]
        if len(board_videos) != len(videos):
            raise UserError(f"{len(board_videos)} board videos for {len(videos)} cameras",
                            "pass one board video per camera, in the order of --videos")
        if board is None:
            raise UserError("board videos given without --board", "pass the printed board's spec, e.g. --board charuco-a1")
    for p in videos + (board_videos or []):
        if not p.is_file():
            raise UserError(f"video not found: {p}", "check the path")
        info = VideoReader(p).info  # a corrupt or non-video file ends here, before anything is written
        if p in videos:  # what every stage will see: the displayed frames
            log.info(f"{names[videos.index(p)]}: {p.name}: {info.describe()}")
    rig = None if calibration is None else _given_calibration(Path(calibration), names, videos, bool(board_videos))
    ws.root.mkdir(parents=True, exist_ok=True)
    if rig is not None:
        from mamma_kit.core.calibfile import write_calibration
        from mamma_kit.core.io import sha256_file
        from mamma_kit.core.manifest import producer

        write_calibration(ws.calibration, rig, producer=producer("mamma-kit init --calibration",
                                                                 {"calibration": sha256_file(Path(calibration))}))
    cams, how = {}, {}
    for i, (n, v) in enumerate(zip(names, videos)):
        dst = ws.root / "videos" / f"{n}{v.suffix.lower()}"
        how[n] = _place(v, dst, copy)
        cams[n] = {"video": ws.relative(dst)}
        if board_videos:
            bdst = ws.root / "board" / f"{n}{board_videos[i].suffix.lower()}"
            _place(board_videos[i], bdst, copy)
            cams[n]["board_video"] = ws.relative(bdst)
    data: dict = {"capture": {"name": ws.root.name, "body_model": "open", **({"people": people} if people else {})},
                  "cameras": cams,
                  "settings": {"track": {"backend": backend}}}
    if synced:  # one clock for all cameras (genlock, a lab rig): no audio needed
        data["settings"]["sync"] = {"method": "synced"}
    if board is not None:
        from mamma_kit.calibration.board import load_board_spec
        from mamma_kit.core.io import write_toml

        spec_path = ws.root / "board" / "board.toml"
        write_toml(spec_path, load_board_spec(board).to_dict())
        data["board"] = {"spec": ws.relative(spec_path)}
    ws.write_capture(data)
    log.info(f"wrote {ws.capture_toml}: {len(cams)} cameras ({', '.join(names)}); videos "
             f"{', '.join(sorted(set(how.values())))}; next: mamma-kit capture-to-smplx {ws.root}")
    return {"workspace": str(ws.root), "capture_toml": str(ws.capture_toml), "cameras": cams,
            "board": data.get("board", {}).get("spec"),
            "calibration": str(ws.calibration) if rig is not None else None}


def _given_calibration(path: Path, names: list[str], videos: list[Path], has_board: bool):
    """The capture's cameras, in video order, from a calibration file of any readable format;
    each must be calibrated at its video's size."""
    from mamma_kit.calibration.formats import read_rig
    from mamma_kit.core.calibfile import check_rig_covers
    from mamma_kit.core.camera import Rig
    from mamma_kit.video import VideoReader

    if has_board:
        raise UserError("both board videos and --calibration given",
                        "pass board videos to calibrate, or a calibration to use as it is, not both")
    rig = read_rig(path)
    check_rig_covers(rig, names, path)
    cams = []
    for n, v in zip(names, videos):
        w, h = VideoReader(v).size
        cw, ch = (int(x) for x in rig[n].size)
        if (w, h) == (cw, ch):
            cams.append(rig[n])
        elif is_codec_padding(cw, w) and is_codec_padding(ch, h):
            # the calibrating system saw the codec's coded picture (rounded up to 16 pixels); the
            # video shows it cropped at the right and bottom, where codecs pad: the pixels that
            # remain keep their coordinates, so K stays and only the size changes
            log.warn(f"{path.name} calibrates camera {n} at {cw}x{ch}, {v.name} is {w}x{h}: taken as the codec's "
                     f"padding to a multiple of 16, cropped at the right and bottom ({cw - w} columns, {ch - h} rows; "
                     f"the principal point kept)")
            cams.append(rig[n].copy(size=(w, h)))
        else:
            raise UserError(f"{path.name} calibrates camera {n} at {cw}x{ch} but {v.name} is shown at {w}x{h}",
                            "use a calibration made at the videos' resolution and orientation (a portrait phone "
                            "video is shown upright: calibrate it upright)")
    return Rig(cams)


def is_codec_padding(calibrated: int, shown: int) -> bool:
    """``calibrated`` is ``shown`` rounded up to the codec's 16-pixel blocks (1088 for 1080)."""
    return calibrated == shown or (calibrated > shown and calibrated % 16 == 0 and calibrated - shown < 16)
