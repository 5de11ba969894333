"""The keypoints stage: masks/<cam>.npz + videos -> keypoints/<cam>.npz (+ report/keypoints/<cam>.png).

For every (frame, track) of the mask tracks, BlazePose's 33 points of that person. A track's region
of interest follows the person from frame to frame (the landmark model's own next-frame ROI) and is
found again by the detector, on the track's masked box, where the track starts or the followed ROI
leaves the track's box. The other people are blanked out of the model's input by the track's mask,
so the points stay with the track where people overlap; where two tracks' masks touch, they are
re-split by the points found and those people read again (``again_on_resplit``). Each camera is a
unit with its own manifest (.cache/keypoints-<cam>.json).
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import numpy as np

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.manifest import StageManifest, producer
from mamma_kit.core.tracks import KeypointTracks, MaskTracks, nearest_frames, track_frame_count
from mamma_kit.keypoints.estimator import MIN_FOLLOW_FLAG
from mamma_kit.keypoints.hands import MIN_PRESENCE as HAND_MIN_PRESENCE

MODEL_NAME = "blazepose-ghum-full"
# a followed ROI is kept while its centre stays inside the track's box grown by this share and its
# side stays within these multiples of the box's longer side (else the detector looks again)
FOLLOW_BOX_GROW = 0.15
FOLLOW_SIDE_RANGE = (0.6, 3.0)


# mask producers whose masks the re-split leaves alone: the pose tracker's are split between people
# by BlazePose's skeletons already (a pixel two people claim goes to the nearer one), and on the real
# recording in shared/real/ re-splitting them moved benchmarks/heldout_view.py's figures within
# their noise (4.19 -> 4.30 %, PCK@10 86.5 -> 86.2 %; the held-out camera's reference moving with
# it); a synthetic capture's ground-truth masks are exact
NO_RESPLIT = ("track --backend pose", "track --backend gt")
RESPLIT_ROUNDS = 2  # demo: MPJPE (stages 1-3) 48.9 mm without, one round 45.4, two 43.7, three 43.5
HAND_MODEL = "mediapipe-hand-landmark-full"  # what reads the hands (points, flag, handedness)


def _follow_ok(roi_4: np.ndarray, box_4: np.ndarray) -> bool:
    w, h = box_4[2] - box_4[0], box_4[3] - box_4[1]
    g = FOLLOW_BOX_GROW * max(w, h)
    inside = box_4[0] - g <= roi_4[0] <= box_4[2] + g and box_4[1] - g <= roi_4[1] <= box_4[3] + g
    lo, hi = FOLLOW_SIDE_RANGE
    return bool(inside and lo * max(w, h) <= roi_4[2] <= hi * max(w, h))


def points_p5(res, j: int) -> np.ndarray:
    """(33, 5) x, y, z, visibility, presence of ROI j of a PoseResult (the layout resplit reads)."""
    return np.concatenate([res.xy[j], res.z[j, :, None], res.visibility[j, :, None], res.presence[j, :, None]], 1)


def keypoints_for_tracks(est, masks: MaskTracks, video_path: Path, blank: bool = True,
                         progress_label: str | None = None, frames: tuple[int, int] | None = None,
                         resplit: bool | int = True, hands=None, rotation: int | None = None, writer=None
                         ) -> tuple[KeypointTracks | None, dict]:
    """33 points for every (frame, track) of one camera's mask tracks, streaming the video once.
    ``frames``: only the mask frames start:stop (a unit of a split camera; the ROIs are found
    afresh by the detector at its first frame). ``resplit`` (rounds, True = RESPLIT_ROUNDS; with
    ``blank`` only): where two people's masks touch, they are re-split by the points found
    (keypoints/resplit.py) and the people whose mask changed are read again on their new mask.
    ``hands``: a keypoints.hands.HandLandmarker that reads both hands of every person found
    (read_hands), or None. ``rotation``: capture.toml's override of the file's display rotation.
    ``writer``: a core.trackrows.RowWriter each frame's rows go to as they are read (a take of
    minutes is never held); None gathers them into the KeypointTracks returned (else None is)."""
    from mamma_kit.video import VideoReader

    reader = VideoReader(video_path, rotation)
    if tuple(reader.size) != tuple(masks.image_size):
        raise UserError(f"masks/{masks.camera}.npz is {masks.image_size[0]}x{masks.image_size[1]} but "
                        f"{reader.path.name} is {reader.size[0]}x{reader.size[1]}",
                        "run `mamma-kit track` again for this camera")
    out = None
    if writer is None:
        out = KeypointTracks.empty(masks.camera, masks.image_size, masks.frame_times, masks.track_ids,
                                   model=MODEL_NAME)
    present = masks.present
    if frames is not None:
        present = present.copy()
        present[:frames[0]] = False
        present[frames[1]:] = False
    vid_idx = nearest_frames(masks.frame_times, reader.timestamps)
    by_video = {int(v): int(t) for t, v in enumerate(vid_idx) if v >= 0 and present[t].any()}
    follow: dict[int, np.ndarray] = {}  # column -> ROI from the previous frame
    last_t: dict[int, int] = {}
    n_det = n_follow = n_again = n_hands = n_pose = n_sure = 0
    rounds = resplit_rounds(resplit) if blank else 0
    t0 = time.perf_counter()
    total = int(present[[t for t in by_video.values()]].sum()) if by_video else 0
    with log.progress(progress_label or f"keypoints {masks.camera}", total) as advance:
        for _i, _t, img in reader.read_indices(sorted(by_video)):
            t = by_video[_i]
            cols = np.flatnonzero(present[t])
            boxes = masks.boxes[t, cols].astype(np.float64)
            mlist = [masks.mask(t, k) for k in cols]
            rois = np.zeros((len(cols), 4))
            need = []
            for j, k in enumerate(cols):
                roi = follow.get(int(k)) if last_t.get(int(k)) == t - 1 else None
                if roi is not None and _follow_ok(roi, boxes[j]):
                    rois[j] = roi
                    n_follow += 1
                else:
                    need.append(j)
            if need:
                rois[need] = est.rois_for_boxes(img, boxes[need], [mlist[j] for j in need] if blank else None)
                n_det += len(need)
            res = est.landmarks(img, rois, masks=mlist if blank else None)
            if rounds and len(cols) > 1:
                n_again += again_on_resplit(est, img, rois, mlist, res, rounds)
            ok = res.score >= MIN_FOLLOW_FLAG
            for j, k in enumerate(cols):
                follow[int(k)] = res.next_rois[j]
                last_t[int(k)] = t
            # one row per person looked at: the points where the model found a pose, its flag for all
            spec = KeypointTracks.cell_spec(res.xy.shape[1])
            rows = {name: np.full((len(cols), *shape), fill, dtype) for name, (shape, dtype, fill) in spec.items()}
            rows["valid"][ok] = True
            for name in ("xy", "z", "visibility", "presence"):
                rows[name][ok] = getattr(res, name)[ok]
            rows["score"][:] = res.score
            if hands is not None and ok.any():
                hand = read_hands(hands, img, res.xy[ok])
                rows["hand_xy"][ok], rows["hand_presence"][ok], rows["hand_right"][ok] = hand
                n_hands += 2 * int(ok.sum())
            n_pose += int(ok.sum())
            n_sure += int((rows["hand_presence"] > HAND_MIN_PRESENCE).sum())
            if writer is not None:
                writer.append(np.full(len(cols), t), cols, **rows)
            else:
                for name, v in rows.items():
                    getattr(out, name)[t, cols] = v
            advance(len(cols))
    secs = time.perf_counter() - t0
    n = int(present.sum())
    summary = {"camera": masks.camera, "instances": n, "with_pose": n_pose,
               "detector_calls": n_det, "followed": n_follow, "resplit": rounds,
               "read_again": n_again, "hands_read": n_hands, "hands_sure": n_sure, "seconds": round(secs, 3),
               "person_frames_per_s": round(n / secs, 1) if secs > 0 else None}
    return out, summary


def read_hands(hands, img: np.ndarray, xy_p33: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Both hands of P people, their ROIs from BlazePose's points xy_p33 (P, 33, 2): the hand
    model's 21 points (P, 2, 21, 2) px, flags (P, 2) and handedness (P, 2), in one batch. The frame is not blanked by
    the masks: a tracker's mask often cuts a hand off, and the ROI already holds one person's hand."""
    from mamma_kit.keypoints.hands import hand_rois

    P = len(xy_p33)
    rois = np.concatenate([hand_rois(xy_p33, 0), hand_rois(xy_p33, 1)])  # (2P, 4): left hands, then right
    r = hands.landmarks(img, rois)
    return r.xy.reshape(2, P, -1, 2).transpose(1, 0, 2, 3), r.presence.reshape(2, P).T, r.right.reshape(2, P).T


def resplit_rounds(resplit: bool | int) -> int:
    """Rounds of re-split and re-read: True = RESPLIT_ROUNDS, False = 0, or the number given."""
    if isinstance(resplit, bool):
        return RESPLIT_ROUNDS if resplit else 0
    if not isinstance(resplit, int) or resplit < 0:
        raise UserError(f"resplit = {resplit!r} is not a number of rounds",
                        "use true, false or a whole number (0 = off) in [settings.keypoints]")
    return resplit


def again_on_resplit(est, img: np.ndarray, rois_n4: np.ndarray, mlist: list, res,
                     rounds: int = RESPLIT_ROUNDS) -> int:
    """The frame's masks re-split by the points in ``res`` (one PoseResult row per mask); the people
    whose mask changed are read again on it, their rows of ``res`` replaced in place. Each round
    re-splits the last round's masks with the last round's points (better points cut better; the
    cut moves less each round). Returns how many readings were made again."""
    from mamma_kit.keypoints.resplit import split_touching

    n = 0
    masks = dict(enumerate(mlist))
    for _ in range(rounds):
        ok = res.score >= MIN_FOLLOW_FLAG
        new = split_touching(masks, {j: points_p5(res, j) if ok[j] else None for j in masks})
        again = [j for j in masks if new[j] is not masks[j] and new[j] is not None and new[j].any()]
        if not again:
            break
        r2 = est.landmarks(img, rois_n4[again], masks=[new[j] for j in again])
        for i, j in enumerate(again):
            if r2.score[i] >= MIN_FOLLOW_FLAG:
                for name in ("xy", "z", "visibility", "presence", "score", "next_rois"):
                    getattr(res, name)[j] = getattr(r2, name)[i]
        masks, n = new, n + len(again)
    return n


def run_keypoints(ws, *, cameras: list[str] | str | None = None, blank: bool = True, pictures: bool = True,
                  force: bool = False, threads: int | None = None, unit_frames: int | None = None,
                  resplit: bool | int = True, hands: bool = True) -> dict:
    """BlazePose keypoints for every tracked person of every camera (see the module docstring).
    ``unit_frames``: frames per unit of work (0: a camera per unit; None: MAMMA_KIT_UNIT_FRAMES).
    ``resplit``: rounds of touching people read again on masks re-split by their points (True =
    RESPLIT_ROUNDS; keypoints_for_tracks). ``hands``: each person's hands read by MediaPipe's hand
    landmarker too (hand_xy, hand_presence in keypoints/<cam>.npz)."""
    from mamma_kit.core.workspace import select_cameras
    from mamma_kit.keypoints.hands import HAND_LANDMARKER
    from mamma_kit.keypoints.runtime import DETECTOR, LANDMARKER, model_path

    cap = ws.load_capture()
    cams = select_cameras(cap.camera_names, cameras)
    missing = [c for c in cams if not ws.mask_file(c).is_file()]
    if missing:
        raise UserError(f"no person masks for {', '.join(missing)} (masks/<cam>.npz)",
                        "run `mamma-kit track WORKSPACE` first")
    models = [model_path(DETECTOR), model_path(LANDMARKER)] + ([model_path(HAND_LANDMARKER)] if hands else [])
    settings = {"model": MODEL_NAME, "blank": blank, "pictures": pictures, "resplit": resplit_rounds(resplit),
                "hands": HAND_MODEL if hands else False}
    t0 = time.perf_counter()
    per_cam, todo = {}, []
    for cam in cams:
        manifest = StageManifest(ws.cache_dir, f"keypoints-{cam}", ws.root)
        inputs = [ws.mask_file(cam), cap.cameras[cam].video, *models]
        state = manifest.check(inputs, {**settings, "camera": cam})
        if state.fresh and not force and ws.keypoints_file(cam).is_file():
            per_cam[cam] = {"camera": cam, "skipped": True, **manifest.load().get("summary", {})}
        else:
            todo.append(cam)
    from mamma_kit.core.executor import frame_ranges, run_units
    _ESTIMATORS.clear()  # a fresh model per call here, as before; workers keep theirs across units

    # units: (camera, frame range); one range per camera unless unit_frames (or
    # MAMMA_KIT_UNIT_FRAMES) splits it. LiteRT uses every core, so locally they run here in order
    units = [(cam, r) for cam in todo for r in frame_ranges(track_frame_count(ws.mask_file(cam)),
                                                          unit_frames)]
    unit = partial(_keypoints_range, root=ws.root, models=models, settings=settings, blank=blank,
                   pictures=pictures, threads=threads)
    parts: dict[str, list] = {cam: [] for cam in todo}
    for (cam, frames), summ in zip(units, run_units(unit, units, threaded=True)):
        parts[cam].append((frames, summ))
    for cam in todo:
        if len(parts[cam]) == 1:  # a whole camera: its unit wrote it (so a stopped run keeps it)
            per_cam[cam] = {"camera": cam, "skipped": False, **parts[cam][0][1]}
            continue
        summ = _joined_summary(cam, [sm for _, sm in parts[cam]])
        per_cam[cam] = {"camera": cam, "skipped": False,
                        **_join_parts(ws, cam, [fr for fr, _ in parts[cam]], summ, models, settings, pictures)}
    ran = todo
    per_cam = [per_cam[c] for c in cams]
    secs = time.perf_counter() - t0
    if not ran:
        log.info("keypoints: up to date (inputs unchanged); skipped (--force recomputes)")
    return {"stage": "keypoints", "skipped": not ran, "reason": "inputs unchanged" if not ran else
            f"ran {', '.join(ran)}", "model": MODEL_NAME, "cameras": per_cam, "seconds": round(secs, 2)}


_ESTIMATORS: dict = {}


def _keypoints_range(unit: tuple[str, tuple[int, int]], root: Path, models: list[Path], settings: dict,
                     blank: bool, pictures: bool, threads: int | None) -> dict:
    """One (camera, frame range), here or in a worker; returns its summary. A whole camera writes
    keypoints/<cam>.npz (rows streamed into it as they are read), its picture and its manifest
    itself; a part of a camera writes a part file that run_keypoints joins."""
    from mamma_kit.core.trackrows import RowWriter
    from mamma_kit.core.workspace import Workspace

    cam, frames = unit
    ws = Workspace(root)
    cap = ws.load_capture()
    if threads not in _ESTIMATORS:  # one estimator per process, as the cameras' loop had
        from mamma_kit.keypoints.estimator import PoseEstimator
        from mamma_kit.keypoints.hands import HandLandmarker

        _ESTIMATORS[threads] = PoseEstimator(threads), HandLandmarker(threads)
    est, hl = _ESTIMATORS[threads]
    hl = hl if settings["hands"] else None
    masks = MaskTracks.load(ws.mask_file(cam))
    resplit = 0 if masks.producer.get("command") in NO_RESPLIT else settings["resplit"]
    whole = frames == (0, len(masks.frame_times))
    path = ws.keypoints_file(cam) if whole else part_file(ws, cam, frames)
    with RowWriter(path, KeypointTracks, _header(masks), 33) as writer:
        _, summ = keypoints_for_tracks(est, masks, cap.cameras[cam].video, blank, frames=None if whole else frames,
                                       progress_label=None if whole else f"keypoints {cam} {frames[0]}-{frames[1]}",
                                       resplit=resplit, hands=hl, rotation=cap.cameras[cam].rotation, writer=writer)
        if not whole:
            writer.close()
            return summ
        return _write_camera(ws, cam, writer, summ, models, settings, pictures)


def _header(masks: MaskTracks) -> dict:
    return {"camera": masks.camera, "image_size": masks.image_size, "frame_times": masks.frame_times,
            "track_ids": masks.track_ids, "model": MODEL_NAME, "producer": {}}


def part_file(ws, cam: str, frames: tuple[int, int]) -> Path:
    """Where a unit of a split camera leaves its rows for the join (beside the camera's file)."""
    return ws.keypoints_dir / f".{cam}.{frames[0]}-{frames[1]}.part.npz"


def _join_parts(ws, cam: str, ranges: list, summ: dict, models: list[Path], settings: dict, pictures: bool) -> dict:
    """keypoints/<cam>.npz from the part files of a split camera, their rows in frame order."""
    from mamma_kit.core.trackrows import RowWriter, TrackFile, copy_rows

    paths = [part_file(ws, cam, fr) for fr in ranges]
    with TrackFile(paths[0], KeypointTracks, "keypoint file") as first:
        header = {**first.header}
    with RowWriter(ws.keypoints_file(cam), KeypointTracks, header, 33) as writer:
        for p in paths:
            with TrackFile(p, KeypointTracks, "keypoint file") as part:
                copy_rows(part, writer)
        out = _write_camera(ws, cam, writer, summ, models, settings, pictures)
    for p in paths:
        p.unlink(missing_ok=True)
    return out


def _joined_summary(cam: str, summaries: list[dict]) -> dict:
    if len(summaries) == 1:
        return summaries[0]
    out = {"camera": cam, **{k: sum(s.get(k, 0) for s in summaries)
                             for k in ("instances", "with_pose", "detector_calls", "followed", "read_again",
                                       "hands_read", "hands_sure")}}
    secs = sum(s["seconds"] for s in summaries)
    out.update({"seconds": round(secs, 3), "units": len(summaries), "resplit": summaries[0].get("resplit"),
                "person_frames_per_s": round(out["instances"] / secs, 1) if secs > 0 else None})
    return out


def _write_camera(ws, cam: str, writer, summ: dict, models: list[Path], settings: dict, pictures: bool) -> dict:
    """keypoints/<cam>.npz (the rows in ``writer``, a core.trackrows.RowWriter, closed here), its
    picture and its manifest."""
    from mamma_kit.core.trackrows import TrackFile

    cap = ws.load_capture()
    manifest = StageManifest(ws.cache_dir, f"keypoints-{cam}", ws.root)
    inputs, out = [ws.mask_file(cam), cap.cameras[cam].video, *models], ws.keypoints_file(cam)
    tc = time.perf_counter()
    hashes = {ws.relative(p): manifest.hasher(p) for p in inputs}
    writer.header["producer"] = producer("keypoints", hashes)
    writer.close()
    outputs = [out]
    if summ["instances"] == 0:
        log.warn(f"{cam}: no tracked person, so no keypoints (an empty keypoints/{cam}.npz)")
    if pictures:
        from mamma_kit.keypoints.pictures import write_keypoints_picture

        with TrackFile(out, KeypointTracks, "keypoint file") as kf:
            pic = write_keypoints_picture(kf, cap.cameras[cam].video, ws.report_dir / "keypoints" / f"{cam}.png",
                                          rotation=cap.cameras[cam].rotation)
        summ["picture"] = ws.relative(pic)
        outputs.append(pic)
    manifest.record(inputs, {**settings, "camera": cam}, outputs, summ, summ["seconds"] + time.perf_counter() - tc)
    log.info(f"{cam}: keypoints for {summ['with_pose']} of {summ['instances']} tracked person-frames "
             f"({summ['person_frames_per_s']} /s)")
    return summ
