"""The fill stage: identities.json + keypoints + masks + videos -> fill/ (tracks where a view lost a
person the others see).

A view's tracker loses people half hidden behind others, and the match can only name the tracks it
has. Here the views help each other: where a person of the capture has no track in a camera but
other cameras see them (filling/gaps.py), BlazePose looks at the place their skeleton projects to
(filling/look.py); what it finds becomes new tracks of that person in that camera. Their keypoints
are the model's points (no second run), their landmarks come from the landmarks stage's network
(landmarks.stage.LandmarksReader). Written: fill/masks/<cam>.npz, fill/keypoints/<cam>.npz,
fill/landmarks/<cam>.npz (only the new tracks, ids after the camera's own) and fill/identities.json
(the match's identities with the new tracks); the stages after read them through core.filled.
"""

from __future__ import annotations

import time

import numpy as np

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.manifest import StageManifest, producer
from mamma_kit.core.trackrows import RowWriter
from mamma_kit.core.tracks import KeypointTracks, MaskTracks

# frames per block when the gaps are triangulated (memory: cameras x frames x persons x 33 points)
BLOCK_FRAMES = 512
# found frames of one person in one camera further apart than this are two tracks
MAX_RUN_GAP = 3
# a run of fewer finds is a glimpse, no track (runs_of)
MIN_FOUND = 2


def runs_of(found: list) -> list[tuple[int, list]]:
    """Per person, runs of found frames (gaps <= MAX_RUN_GAP) of at least MIN_FOUND finds: (person,
    finds). A lone find is a glimpse, as the tracker's shortest tracks are: most are a sliver of
    someone another track's mask half covers (crowd-6, room-wander: every fill track on no person
    was one)."""
    by_person: dict[int, list] = {}
    for fd in found:
        by_person.setdefault(fd.person, []).append(fd)
    runs = []
    for p, items in sorted(by_person.items()):
        items.sort(key=lambda x: x.frame)
        cur = [items[0]]
        for fd in items[1:]:
            if fd.frame - cur[-1].frame > MAX_RUN_GAP:
                runs.append((p, cur))
                cur = []
            cur.append(fd)
        runs.append((p, cur))
    return [r for r in runs if len(r[1]) >= MIN_FOUND]


def new_tracks(cam: str, masks: MaskTracks, runs: list, keypoints_path) -> tuple[MaskTracks, dict[int, int]]:
    """Each run of finds (runs_of) as a track with an id after the camera's own. Writes their
    keypoints (the model's points) to ``keypoints_path`` and returns their masks and track id ->
    person id."""
    runs = sorted(runs, key=lambda r: (r[1][0].frame, r[0]))  # columns in order of first frame, as the tracker's
    first_id = int(masks.track_ids.max()) + 1 if len(masks.track_ids) else 0
    ids = first_id + np.arange(len(runs), dtype=np.int64)
    mt = MaskTracks.from_masks(cam, masks.image_size, masks.frame_times, ids,
                               {(fd.frame, k): fd.mask for k, (_, items) in enumerate(runs) for fd in items},
                               {(fd.frame, k): fd.score for k, (_, items) in enumerate(runs) for fd in items},
                               producer("fill"))
    cells = sorted((fd.frame, k, fd) for k, (_, items) in enumerate(runs) for fd in items)
    header = {"camera": cam, "image_size": masks.image_size, "frame_times": masks.frame_times,
              "track_ids": mt.track_ids, "model": "blazepose-ghum-full", "producer": producer("fill")}
    with RowWriter(keypoints_path, KeypointTracks, header, 33) as w:
        if cells:
            p5 = np.stack([fd.points_p5 for *_, fd in cells])  # (n, 33, 5)
            w.append([t for t, *_ in cells], [k for _, k, _ in cells], valid=np.ones(len(cells), bool),
                     xy=p5[..., :2], z=p5[..., 2], visibility=p5[..., 3], presence=p5[..., 4],
                     score=np.array([fd.score for *_, fd in cells], np.float32))
        w.close()
    return mt, {int(mt.track_ids[k]): int(p) for k, (p, _) in enumerate(runs)}


def _camera_gaps(cam: str, cams: list[str], per_cam: dict, covered_tp: np.ndarray, rig, persons: list[int]):
    from mamma_kit.filling.gaps import Gaps, find_gaps

    times = per_cam[cam][0]
    parts = []
    for a in range(0, len(times), BLOCK_FRAMES):
        b = min(a + BLOCK_FRAMES, len(times))
        g = find_gaps(cam, times[a:b], covered_tp[a:b], {c: per_cam[c] for c in cams}, rig, persons)
        g.frame_g = g.frame_g + a
        parts.append(g)
    return Gaps(*(np.concatenate([getattr(g, f) for g in parts]) for f in ("frame_g", "person_g", "xy_g332",
                                                                          "views_g")))


def run_fill(ws, *, force: bool = False, enabled: bool = True) -> dict:
    """Fill every camera's gaps (module docstring); ``enabled`` False removes an earlier fill."""
    import shutil

    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.filled import FILL_IDENTITIES, identities_digest
    from mamma_kit.core.identities import read_identities, write_identities
    from mamma_kit.core.timingfile import clocks_or_synced
    from mamma_kit.core.trackrows import TrackFile
    from mamma_kit.filling.gaps import person_points, persons_per_frame
    from mamma_kit.filling.look import look
    from mamma_kit.keypoints.estimator import PoseEstimator
    from mamma_kit.landmarks.stage import LandmarksReader
    from mamma_kit.video import VideoReader

    t0 = time.perf_counter()
    if not enabled:
        shutil.rmtree(ws.fill_dir, ignore_errors=True)
        return {"stage": "fill", "skipped": True, "reason": "off (capture.toml [settings.fill] enabled = false)"}
    for p, run in ((ws.identities, "match"), (ws.calibration, "calibrate")):
        if not p.is_file():
            raise UserError(f"the fill needs {p.name}, and {ws.root} has none", f"run `mamma-kit {run} WORKSPACE` first")
    ident = read_identities(ws.identities)
    cap = ws.load_capture()
    if cap.stage_settings("landmarks").get("source", "net") == "gt":
        shutil.rmtree(ws.fill_dir, ignore_errors=True)
        return {"stage": "fill", "skipped": True, "reason": "ground-truth landmarks: no network to read new tracks"}
    cams = [c for c in ident.cameras if c in cap.cameras and ws.mask_file(c).is_file()
            and ws.keypoints_file(c).is_file()]
    options = cap.stage_settings("landmarks")
    settings = {"landmarks": {k: str(v) for k, v in sorted(options.items())}}
    inputs = [p for p in (ws.identities, ws.calibration, ws.timing) if p.is_file()] + [p for c in cams for p in
                                                           (ws.mask_file(c), ws.keypoints_file(c), cap.cameras[c].video)]
    manifest = StageManifest(ws.cache_dir, "fill", ws.root)
    again = manifest.reuse(manifest.check(inputs, settings), force, ws.fill_dir / FILL_IDENTITIES)
    if again is not None:
        return again
    rig, _ = read_calibration(ws.calibration)
    clocks = clocks_or_synced(ws.timing, cams)
    persons = ident.person_ids
    masks, per_cam, covered = {}, {}, {}
    for c in cams:
        masks[c] = MaskTracks.load(ws.mask_file(c))
        with TrackFile(ws.keypoints_file(c), KeypointTracks, "keypoint file") as kf:
            times = clocks[c].to_ref(kf.frame_times)
            col_tp = persons_per_frame(ident.person_frames(c, kf.track_ids, times), masks[c].present, persons)
            per_cam[c] = (times, *person_points(kf, col_tp))
        covered[c] = col_tp >= 0
    est = PoseEstimator()
    shutil.rmtree(ws.fill_dir, ignore_errors=True)
    outputs, per_camera, read_landmarks = [], [], None
    for c in cams:
        gaps = _camera_gaps(c, cams, per_cam, covered[c], rig, persons)
        entry = cap.cameras[c]
        with TrackFile(ws.keypoints_file(c), KeypointTracks, "keypoint file") as kf:
            found = look(est, VideoReader(entry.video, entry.rotation), masks[c], gaps, f"fill {c}", kf)
        runs = runs_of(found)
        row = {"camera": c, "gaps": len(gaps), "found": sum(len(run) for _, run in runs), "tracks": 0}
        if runs:
            mt, person_of = new_tracks(c, masks[c], runs, ws.fill_file("keypoints", c))
            outputs += [ws.fill_file("keypoints", c), mt.save(ws.fill_file("masks", c))]
            if read_landmarks is None:
                read_landmarks = LandmarksReader(options)
            outputs.append(read_landmarks.write(ws, c, mt, ws.fill_file("keypoints", c), ws.fill_file("landmarks", c)))
            ident.assignments.setdefault(c, {}).update(person_of)
            for tid in person_of:
                ident.track_frames[(c, tid)] = int(mt.present[:, list(mt.track_ids).index(tid)].sum())
            row["tracks"] = len(person_of)
        per_camera.append(row)
        log.info(f"fill {c}: {row['found']} of {row['gaps']} gaps found, {row['tracks']} tracks")
    ident.settings = {**ident.settings, "fill": {"from_identities": identities_digest(ws.identities),
                                                 "person_view_frames": sum(r["found"] for r in per_camera)}}
    outputs.append(write_identities(ws.fill_dir / FILL_IDENTITIES, ident))
    secs = time.perf_counter() - t0
    summary = {"stage": "fill", "skipped": False, "cameras": per_camera, "seconds": round(secs, 2),
               "found": sum(r["found"] for r in per_camera), "gaps": sum(r["gaps"] for r in per_camera)}
    manifest.record(inputs, settings, outputs, summary, secs)
    return summary
