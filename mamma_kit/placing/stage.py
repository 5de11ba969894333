"""The place stage: the fitted bodies -> place/ (tracks where a view lost a person it still sees).

A person more than half hidden behind others is where BlazePose finds no body, in the tracker and
in the fill alike (crowd-6: the seen person-view-frames no track covers show 26-40 % of the person).
The fit knows where they are from the other views. Per camera and frame, a fitted person with no
track there is placed when
- the camera sees at least MIN_SHARE of their silhouette (placing.silhouettes: the bodies' z-buffer),
- at least MIN_VIEWS other views' tracks follow them at that instant, and
- where the other bodies hide little of them (SCENE_SHARE), the image shows a person there
  (BlazePose's person segmentation on the body's square): walls and door frames hide people the
  bodies' z-buffer knows nothing of.
A silhouette that a track without a person at that frame already covers names that track instead.
A track whose mask is another fitted person's visible silhouette and not its own person's is given
that person for the frame, or no one where that person's own track is there too (looked at where
the track's box lies nearer another person's projected joints than its own person's).
Placements of one person in one camera form tracks as the fill's do (filling.stage.runs_of: gaps of
at most three frames, a lone placement is a glimpse). Written: place/masks/<cam>.npz (the placed
tracks' visible silhouettes, ids after the camera's own and the fill's) and place/identities.json
(the identities the fit read, with the placed tracks); core.filled reads them with ``placed=True``.
They carry masks only: the fit reads the tracks the networks saw.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.manifest import StageManifest, producer

MIN_SHARE = 0.25
MIN_VIEWS = 2
# a person of whose silhouette the other bodies leave this share or more in view (someone standing
# free whom the view lost, or someone the scene hides: a wall, a door frame, which the fit knows
# nothing of) is placed only where BlazePose's person segmentation covers MIN_SUPPORT of the
# silhouette (room-wander: every placement on a person wholly hidden in that view had the whole
# silhouette free of other bodies)
SCENE_SHARE = 0.8
MIN_SUPPORT = 0.3
WORK_SIDE = 640  # silhouettes are rendered at most this long (px), masks scaled up to the video's size
MIN_PX = 40  # a visible silhouette of fewer pixels (at the working size) is no placement
PLACED_SCORE = 0.1  # masks no detector confirmed score as the tracker's coasting slivers
NAME_IOU = 0.3  # a silhouette and the mask of a track without a person at this IoU are one body
SAME_BODY, NOT_BODY = 0.3, 0.2  # a labelled track's mask: another's silhouette at IoU >= 0.3, its own's < 0.2
ROI_GROW = 1.25  # the image check's square: the fitted body's extent grown by this
BLOCK_FRAMES = 64  # fitted frames posed at once (memory: persons x frames x 10,475 vertices)


@dataclass
class Placed:
    """One placement: the camera's frame, the person, the mask (encode_mask: runs and box)."""

    frame: int
    person: int  # index among the fitted persons
    mask: tuple
    share: float  # of the silhouette the camera sees
    support: float  # of the placed mask the image's person segmentation covers (1: not asked)


def followed(times_t: np.ndarray, has_tp: np.ndarray, query_q: np.ndarray, tol: float) -> np.ndarray:
    """(Q, P) whether a view follows each person within ``tol`` of each query time: ``has_tp``
    (T, P) whether its tracks show each person at its frames' reference times ``times_t``."""
    from mamma_kit.core.tracks import nearest_frames

    return np.stack([nearest_frames(query_q, times_t[has_tp[:, p]], tol) >= 0 for p in range(has_tp.shape[1])], 1) \
        if has_tp.shape[1] else np.zeros((len(query_q), 0), bool)


def doubtful(track_boxes_tk4: np.ndarray, person_tk: np.ndarray, body_boxes_tp4: np.ndarray) -> np.ndarray:
    """(T,) the frames where a track with a person lies nearer (box IoU) another fitted person's
    projected joints than its own person's: where a track may show someone else."""
    from mamma_kit.keypoints.blazepose import box_iou

    iou = box_iou(track_boxes_tk4, body_boxes_tp4)  # (T, K, P)
    own = np.take_along_axis(iou, np.maximum(person_tk, 0)[..., None], -1)[..., 0]
    return ((person_tk >= 0) & (iou.max(-1) > own)).any(1)


def candidates(c: str, views: dict, t_q: np.ndarray) -> np.ndarray:
    """(Q, P) the persons to try placing in camera ``c`` at its frames' reference times ``t_q``: no
    track of theirs there now, and MIN_VIEWS other views' tracks follow them now. ``views``: camera
    -> (reference times (T,), has (T, P), frame period)."""
    times, has, period = views[c]
    now = followed(times, has, t_q, 0.25 * period)
    others = sum(followed(t, h, t_q, 0.5 * per + 1e-6).astype(np.int64)
                 for o, (t, h, per) in views.items() if o != c)
    return ~now & (np.asarray(others) >= MIN_VIEWS)


def place_camera(cam, frames, masks, person_tk: np.ndarray, want_tp: np.ndarray, verts_of, est=None
                 ) -> tuple[list, list]:
    """One camera's placements and the frames of its tracks to give another person. ``frames``
    yields (frame, image) for the frames to look at (those where ``want_tp`` (T, P) has persons to
    try, and those where tracks may show someone else), ``masks`` its tracks (core.tracks.MaskTracks,
    the fill's with them), ``person_tk`` (T, K) each one's person index per frame (-1 none),
    ``verts_of(t)`` every fitted body's vertices at frame t (list of (V, 3) or None), ``cam`` the
    camera, ``est`` a keypoints.estimator.PoseEstimator for the image check (None: no check).

    Returned: placements (Placed) and ``relabel`` ((frame, column, person index; -1 none)): a track
    whose mask a fitted person's visible silhouette fits (IoU >= SAME_BODY) while its own person's
    does not (< NOT_BODY) shows that person then (a tracker that handed the front person's body to
    the hidden one's track for a frame), or no one where that person's own track is there too; a
    silhouette that the mask of a track without a person then overlaps (NAME_IOU) names that track.
    Else a person to try is placed (a person's mask from the tracker can hold the sliver of the one
    behind: that track is left as it is), where the image shows a person if the bodies hide little
    of them (SCENE_SHARE, MIN_SUPPORT)."""
    import cv2

    from mamma_kit.core.tracks import encode_mask
    from mamma_kit.placing.silhouettes import front_labels, visible_silhouette

    W, H = masks.image_size
    s = min(1.0, WORK_SIDE / max(W, H))
    cam_work = cam.scaled(s) if s < 1.0 else cam
    w, h = cam_work.size
    placed, relabel = [], []
    for t, img in frames:
        verts = verts_of(t)
        label, alone = front_labels(cam_work, verts, w, h)
        sil = {p: visible_silhouette(label, p) for p in range(len(verts)) if verts[p] is not None}
        ks = np.flatnonzero(masks.present[t])
        small = {int(k): cv2.resize(masks.mask(t, k).astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST
                                    ).astype(bool) for k in ks}
        iou_kp = np.array([[(m & sil[p]).sum() / max((m | sil[p]).sum(), 1) if p in sil else 0.0
                            for p in range(len(verts))] for m in small.values()]).reshape(len(ks), len(verts))
        now = person_tk[t, ks].copy()
        for i, k in enumerate(ks):  # a labelled track on another fitted person's body
            p = now[i]
            q = int(np.argmax(iou_kp[i])) if iou_kp.shape[1] else -1
            if p >= 0 and q != p and iou_kp[i, q] >= SAME_BODY and iou_kp[i, p] < NOT_BODY:
                now[i] = q if q not in now else -1  # ... whose own track is there too: a second one on them
                relabel.append((int(t), int(k), int(now[i])))
        here = []
        for p in np.flatnonzero(want_tp[t]):
            seen = int((label == p).sum())
            if verts[p] is None or p in now or seen < MIN_PX or seen < MIN_SHARE * alone[p]:
                continue
            free = [i for i in range(len(ks)) if now[i] < 0]
            i = max(free, key=lambda i: iou_kp[i, p], default=None)
            if i is not None and iou_kp[i, p] >= NAME_IOU:
                relabel.append((int(t), int(ks[i]), int(p)))
                now[i] = p
                continue
            m = cv2.resize(sil[p].astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).astype(bool)
            here.append((int(p), m, seen / max(alone[p], 1)))
        # nothing the fit knows of hides them: the image must show a person there
        check = [i for i, h_ in enumerate(here) if h_[2] >= SCENE_SHARE]
        support = dict(zip(check, person_support(est, img, cam, [verts[here[i][0]] for i in check],
                                                 [here[i][1] for i in check]))) if check and est is not None else {}
        placed += [Placed(int(t), p, encode_mask(m), share, support.get(i, 1.0)) for i, (p, m, share) in enumerate(here)
                   if support.get(i, 1.0) >= MIN_SUPPORT]
    return placed, relabel


def person_support(est, img: np.ndarray, cam, verts: list[np.ndarray], masks_hw: list[np.ndarray]) -> list[float]:
    """Per placement, the share of its mask that BlazePose's person segmentation covers, the model run
    on the square around the whole fitted body (a wall or a door frame in front of the person is no
    person); 0 where the model flags no person in the square."""
    from mamma_kit.keypoints.estimator import MIN_POSE_FLAG
    from mamma_kit.masks.pose import SEG_THRESHOLD

    H, W = img.shape[:2]
    rois = []
    for v in verts:
        uv = cam.project(v)
        uv = uv[np.isfinite(uv).all(1)]
        lo, hi = uv.min(0), uv.max(0)
        rois.append([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, ROI_GROW * float(max(hi - lo)), 0.0])
    res = est.landmarks(img, np.array(rois))
    out = []
    for n, m in enumerate(masks_hw):
        prob, (x0, y0) = res.segmentation_of(n, (W, H))  # over its box, inside the image
        covered = (m[y0:y0 + prob.shape[0], x0:x0 + prob.shape[1]] & (prob > SEG_THRESHOLD)).sum()
        # the segmentation of a crop without a person is no evidence: the model's person flag says so
        out.append(float(covered / max(m.sum(), 1)) if res.score[n] >= MIN_POSE_FLAG else 0.0)
    return out


class FittedBodies:
    """The fitted persons' vertices at reference times, posed a block of fitted frames at a time
    (the block last asked for kept: the cameras ask for nearby instants in turn)."""

    def __init__(self, model, results: list):
        self.model, self.results = model, results
        self.period = [float(np.median(np.diff(r.frame_times))) if len(r.frame_times) > 1 else 1.0 for r in results]
        self._blocks: dict[int, tuple[int, np.ndarray]] = {}

    def frames_at(self, p: int, times: np.ndarray) -> np.ndarray:
        """(n,) the fitted frame of person p at each reference time, -1 where none within half a period."""
        from mamma_kit.core.tracks import nearest_frames

        return nearest_frames(np.atleast_1d(times), self.results[p].frame_times, 0.5 * self.period[p] + 1e-6)

    def boxes(self, cam, times: np.ndarray) -> np.ndarray:
        """(T, P, 4) each person's fitted joints' box (x0, y0, x1, y1) in camera ``cam`` at the
        reference ``times``; NaN where not fitted then or behind the camera."""
        out = np.full((len(times), len(self.results), 4), np.nan)
        for p, r in enumerate(self.results):
            k = self.frames_at(p, times)
            ok = k >= 0
            if not ok.any():
                continue
            uv = cam.project(r.joints[k[ok]])  # (n, 55, 2)
            with warnings.catch_warnings():  # a body wholly behind the camera: NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                out[ok, p] = np.concatenate([np.nanmin(uv, 1), np.nanmax(uv, 1)], 1)
        return out

    def vertices(self, t_ref: float) -> list:
        from mamma_kit.body.lbs import pose_mesh_np

        out = []
        for p, r in enumerate(self.results):
            k = int(self.frames_at(p, t_ref)[0])
            if k < 0:
                out.append(None)
                continue
            b0 = (k // BLOCK_FRAMES) * BLOCK_FRAMES
            if self._blocks.get(p, (-1,))[0] != b0:
                sel = np.arange(b0, min(b0 + BLOCK_FRAMES, len(r.frame_times)))
                self._blocks[p] = (b0, pose_mesh_np(self.model, r.params(sel))[0])
            out.append(self._blocks[p][1][k - b0])
        return out


def relabel_frames(ident, cam: str, masks, t_ref: np.ndarray, changes: list, pids: list[int]) -> None:
    """Give the frames ``changes`` ((frame, column, person index; -1 none)) of the camera's tracks
    those persons, in ``ident``: each changed track's person per frame, rebuilt into segments (runs of one
    person over the frames the track is present in; identities' segments)."""
    by_col: dict[int, list] = {}
    for t, k, p in changes:
        by_col.setdefault(int(k), []).append((int(t), pids[p] if p >= 0 else -1))
    segs = [sg for sg in ident.segments.get(cam, []) if int(sg[0]) not in {int(masks.track_ids[k]) for k in by_col}]
    for k, items in sorted(by_col.items()):
        tid = int(masks.track_ids[k])
        who = ident.person_frames(cam, np.array([tid]), t_ref)[:, 0]
        for t, pid in items:
            who[t] = pid
        f = np.flatnonzero(masks.present[:, k])
        runs = np.split(np.arange(len(f)), np.flatnonzero(np.diff(who[f]) != 0) + 1)
        segs += [(tid, float(t_ref[f[r[0]]]), float(t_ref[f[r[-1]]]), int(who[f[r[0]]])) for r in runs
                 if len(r) and who[f[r[0]]] >= 0]
        ids, counts = np.unique(who[f][who[f] >= 0], return_counts=True)
        if len(ids):
            ident.assignments.setdefault(cam, {})[tid] = int(ids[np.argmax(counts)])
    if segs:
        ident.segments[cam] = segs


def who_is_where(ident, masks: dict, clocks: dict, pids: list[int]) -> tuple[dict, dict]:
    """Per camera: (reference times (T,), which fitted persons its tracks show at each frame (T, P),
    frame period) and each track's person index per frame (T, K) (-1 none); ``masks``: camera ->
    its tracks (the fill's with them)."""
    views, person_tk = {}, {}
    for c, mt in masks.items():
        t_ref = clocks[c].to_ref(mt.frame_times)
        p_tk = ident.person_frames(c, mt.track_ids, t_ref)
        person_tk[c] = np.full(p_tk.shape, -1, np.int64)
        for i, p in enumerate(pids):
            person_tk[c][p_tk == p] = i
        has = np.stack([((p_tk == p) & mt.present).any(1) for p in pids], 1) if pids else \
            np.zeros((len(t_ref), 0), bool)
        views[c] = (t_ref, has, float(np.median(np.diff(t_ref))) if len(t_ref) > 1 else 1.0)
    return views, person_tk


def write_placed(path, masks, runs: list, ident, pids: list[int]):
    """The runs of placements (filling.stage.runs_of) as tracks with ids after the camera's own
    ``masks``: written to ``path``, and given their persons in ``ident``."""
    from mamma_kit.core.tracks import MaskTracks

    first = int(masks.track_ids.max()) + 1 if len(masks.track_ids) else 0
    runs = sorted(runs, key=lambda r: (r[1][0].frame, r[0]))  # columns in order of first frame
    ids = first + np.arange(len(runs), dtype=np.int64)
    mt = MaskTracks.from_masks(masks.camera, masks.image_size, masks.frame_times, ids,
                               {(pl.frame, k): pl.mask for k, (_, items) in enumerate(runs) for pl in items},
                               {(pl.frame, k): PLACED_SCORE for k, (_, items) in enumerate(runs) for pl in items},
                               producer("place"))
    for k, (p, items) in enumerate(runs):
        ident.assignments.setdefault(masks.camera, {})[int(ids[k])] = pids[p]
        ident.track_frames[(masks.camera, int(ids[k]))] = len(items)
    return mt.save(path)


def place_picture(ws, cam: str, masks, placed, ident, t_ref: np.ndarray):
    """report/place/<cam>.png: the frame with the most placed tracks, every track tinted by its
    person, the placed ones labelled so."""
    import cv2

    from mamma_kit.core.io import atomic_path
    from mamma_kit.core.tracks import append_tracks
    from mamma_kit.matching.pictures import draw_identities
    from mamma_kit.video.reader import VideoReader

    mt = append_tracks(masks, placed)
    t = int(np.argmax(placed.present.sum(1)))
    entry = ws.load_capture().cameras[cam]
    _, rgb = VideoReader(entry.video, entry.rotation).frame_index(t)
    person = ident.person_frames(cam, mt.track_ids, t_ref)[t]
    img = draw_identities(rgb, mt, t, person, {}, cam, {int(i): "placed" for i in placed.track_ids})
    path = ws.report_dir / "place" / f"{cam}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, ".png") as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {path}")
    return path


def run_place(ws, *, force: bool = False, enabled: bool = True) -> dict:
    """Place every camera's hidden people (module docstring); ``enabled`` False removes an earlier run."""
    import shutil

    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.filled import FILL_IDENTITIES, identities_source, fit_digest, identities_digest, load_masks
    from mamma_kit.core.identities import read_identities, write_identities
    from mamma_kit.core.smplxfile import read_smplx_result
    from mamma_kit.core.timingfile import clocks_or_synced
    from mamma_kit.core.tracks import MaskTracks, nearest_frames
    from mamma_kit.filling.stage import runs_of
    from mamma_kit.keypoints.estimator import PoseEstimator
    from mamma_kit.video import VideoReader

    t0 = time.perf_counter()
    if not enabled:
        shutil.rmtree(ws.place_dir, ignore_errors=True)
        shutil.rmtree(ws.report_dir / "place", ignore_errors=True)
        return {"stage": "place", "skipped": True, "reason": "off (capture.toml [settings.place] enabled = false)"}
    for p, run in ((ws.identities, "match"), (ws.calibration, "calibrate")):
        if not p.is_file():
            raise UserError(f"placing needs {p.name}, and {ws.root} has none", f"run `mamma-kit {run} WORKSPACE` first")
    files = ws.person_files()
    if not files:
        raise UserError(f"placing needs the fitted bodies, and {ws.smplx_dir} holds none",
                        "run `mamma-kit fit WORKSPACE` first")
    cap = ws.load_capture()
    source = identities_source(ws)
    ident = read_identities(source)
    cams = [c for c in ident.cameras if c in cap.cameras and ws.mask_file(c).is_file()]
    inputs = [source, ws.calibration] + ([ws.timing] if ws.timing.is_file() else []) + files + \
        [p for c in cams for p in (ws.mask_file(c), ws.fill_file("masks", c)) if p.is_file()]
    settings = {"min_share": MIN_SHARE, "min_views": MIN_VIEWS, "scene_share": SCENE_SHARE, "min_support": MIN_SUPPORT,
                "work_side": WORK_SIDE}
    manifest = StageManifest(ws.cache_dir, "place", ws.root)
    again = manifest.reuse(manifest.check(inputs, settings), force, ws.place_dir / FILL_IDENTITIES)
    if again is not None:
        return again
    rig, _ = read_calibration(ws.calibration)
    clocks = clocks_or_synced(ws.timing, cams)
    cams = [c for c in cams if c in rig]
    pids = [int(f.stem.split("_")[1]) for f in files]
    bodies = FittedBodies(load_body_model(cap.body_model), [read_smplx_result(f) for f in files])
    masks = {c: load_masks(ws, c) for c in cams}
    views, person_tk = who_is_where(ident, masks, clocks, pids)
    est = None  # BlazePose, for the image check: loaded where a camera has someone to place
    shutil.rmtree(ws.place_dir, ignore_errors=True)
    shutil.rmtree(ws.report_dir / "place", ignore_errors=True)
    outputs, per_camera = [], []
    for c in cams:
        t_ref = views[c][0]
        want = candidates(c, views, t_ref)
        look = want.any(1) | doubtful(masks[c].boxes, person_tk[c], bodies.boxes(rig[c], t_ref))
        found, relabel = [], []
        if look.any():
            est = est or PoseEstimator()
            entry = cap.cameras[c]
            reader = VideoReader(entry.video, entry.rotation)
            vid_idx = nearest_frames(masks[c].frame_times, reader.timestamps)
            by_video = {int(vid_idx[t]): int(t) for t in np.flatnonzero(look) if vid_idx[t] >= 0}
            frames = ((by_video[i], img) for i, _, img in
                      log.track(reader.read_indices(sorted(by_video)), f"place {c}", total=len(by_video)))
            found, relabel = place_camera(rig[c], frames, masks[c], person_tk[c], want,
                                          lambda t: bodies.vertices(float(t_ref[t])), est)
        runs = runs_of(found)
        relabel_frames(ident, c, masks[c], t_ref, relabel, pids)
        row = {"camera": c, "tried": int(want.sum()), "placed": sum(len(r) for _, r in runs), "tracks": len(runs),
               "relabelled": len(relabel)}
        if runs:
            path = write_placed(ws.place_dir / "masks" / f"{c}.npz", masks[c], runs, ident, pids)
            outputs += [path, place_picture(ws, c, masks[c], MaskTracks.load(path), ident, t_ref)]
        per_camera.append(row)
        log.info(f"place {c}: {row['placed']} person-frames placed of {row['tried']} tried, {row['tracks']} tracks; "
                 f"{row['relabelled']} track-frames given the person they show")
    ident.settings = {**ident.settings, "place": {"from_identities": identities_digest(source),
                                                  "from_fit": fit_digest(ws),
                                                  "person_view_frames": sum(r["placed"] for r in per_camera)}}
    outputs.append(write_identities(ws.place_dir / FILL_IDENTITIES, ident))
    secs = time.perf_counter() - t0
    summary = {"stage": "place", "skipped": False, "cameras": per_camera, "seconds": round(secs, 2),
               "placed": sum(r["placed"] for r in per_camera), "tracks": sum(r["tracks"] for r in per_camera),
               "relabelled": sum(r["relabelled"] for r in per_camera)}
    manifest.record(inputs, settings, outputs, summary, secs)
    return summary
