"""`mamma-kit match`: cross-view identities of the per-view tracks -> identities.json.

Inputs: landmarks/<cam>.npz (per view tracks), calibration.toml, and timing.toml to pair the
unsynchronised cameras' frames by time (without it, frames are paired by index, with a
warning); keypoints/<cam>.npz where the keypoints stage ran. Output: core.identities.Identities.

Two sources of evidence per camera pair where keypoints exist: the dense landmarks and the
keypoint model's 33 points, each giving every track pair a distance. The more reliable source
decides: the one whose same-person distances are lower on that camera pair (the median over
tracks of each track's best distance: the source's own noise there), wherever it has evidence
for a track pair; the other fills in where it has none. On real footage with a network trained
on renders the landmarks can be far noisier than the keypoints; on renders they are close.

Constants (distances in units of the person's height in the image, see pairs.py):

- ``lam = 0.05``: affinity exp(-D / lam). The official code uses exp(-D / 50 px) at its
  capture resolution; 5 % of the body height is the same order for a full-body person
  ~1000 px tall, and unlike pixels it does not change with resolution or distance.
- ``max_distance = 0.12``: affinity 0 above it (official: 80 px). Same person: D is the landmark
  noise (1.2 % of the height gives D ~ 0.02) plus outliers (capped). Different people: most
  landmarks are tens of percent of a height off the epipolar line (D ~ 0.2+), except people who
  stand on one epipolar plane of that camera pair for the whole tracklet.
- ``min_affinity = 0.25`` (D < 0.069) to keep an assignment or merge groups (official: 0.4 at
  50 px = D < 46 px).
- ``min_landmarks = 20`` shared landmark observations over the tracklet, at least one frame
  with 5 (official: 5 in the frame).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mamma_kit.core import log
from mamma_kit.core.calibfile import read_calibration
from mamma_kit.core.errors import UserError
from mamma_kit.core.identities import Identities
from mamma_kit.core.workspace import Workspace
from mamma_kit.matching.grouping import Node, group_tracks
from mamma_kit.matching.pairs import ViewTracks, pair_distances
from mamma_kit.matching.sources import ViewSource


@dataclass
class MatchSettings:
    lam: float = 0.05
    max_distance: float = 0.12
    min_affinity: float = 0.25
    min_landmarks: int = 20
    min_per_frame: int = 5
    cap: float = 0.25
    vis_threshold: float = 0.5
    max_frames: int = 150
    coexist_tolerance: int = 2
    use_keypoints: bool = True


def source_noise(D: np.ndarray, ev: np.ndarray) -> float:
    """A source's same-person distance on a camera pair: median over tracks of their best distance."""
    Dm = np.where(ev, np.nan_to_num(D, nan=np.inf), np.inf)
    best = np.concatenate([Dm.min(1) if Dm.shape[1] else [], Dm.min(0) if Dm.shape[0] else []])
    best = best[np.isfinite(best)]
    return float(np.median(best)) if len(best) else float("inf")


def affinity_of(D: np.ndarray, n_shared: np.ndarray, frames: np.ndarray, s: MatchSettings) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        A = np.exp(-np.nan_to_num(D, nan=np.inf) / s.lam)
    ok = (n_shared >= s.min_landmarks) & (frames >= 1) & (np.nan_to_num(D, nan=np.inf) <= s.max_distance)
    return np.where(ok, A, 0.0)


def _nan_none(a: np.ndarray, digits: int = 4) -> list:
    return [[None if not np.isfinite(v) else round(float(v), digits) for v in row] for row in np.asarray(a, float)]


def match_views(views: list[ViewTracks], settings: MatchSettings | None = None,
                kp_views: list[ViewTracks | None] | None = None) -> Identities:
    """Identities of the tracks of the given views (see module doc); ``kp_views``: per view the
    keypoint tracks of the same track ids, or None."""
    s = settings or MatchSettings()
    names = [v.name for v in views]
    nodes: list[Node] = []
    node_of: dict[tuple[int, int], int] = {}
    unassigned = []
    for vi, v in enumerate(views):
        for k, tid in enumerate(v.track_ids):
            if not v.valid_tk[:, k].any():
                unassigned.append({"camera": v.name, "track": int(tid), "reason": "no frame with landmarks"})
                continue
            node_of[(vi, k)] = len(nodes)
            nodes.append(Node(vi, int(tid), v.valid_tk[:, k].copy()))
    N = len(nodes)
    A = np.zeros((N, N))
    evidence = np.zeros((N, N), bool)
    pairs: dict = {}
    view_pairs = []
    for a in range(len(views)):
        for b in range(a + 1, len(views)):
            va, vb = views[a], views[b]
            r = pair_distances(va, vb, cap=s.cap, max_frames=s.max_frames, min_per_frame=s.min_per_frame)
            source = "landmarks"
            if kp_views is not None and kp_views[a] is not None and kp_views[b] is not None:
                r, source = _more_reliable(r, pair_distances(kp_views[a], kp_views[b], cap=s.cap,
                                                             max_frames=s.max_frames, min_per_frame=s.min_per_frame), s)
            Ap = affinity_of(r.distance, r.shared_landmarks, r.shared_frames, s)
            ev = (r.shared_landmarks >= s.min_landmarks) & (r.shared_frames >= 1)
            for i in range(va.n_tracks):
                for j in range(vb.n_tracks):
                    x, y = node_of.get((a, i)), node_of.get((b, j))
                    if x is None or y is None:
                        continue
                    A[x, y] = A[y, x] = Ap[i, j]
                    evidence[x, y] = evidence[y, x] = ev[i, j]
            pairs[f"{va.name}|{vb.name}"] = {
                "rows": va.track_ids.tolist(), "cols": vb.track_ids.tolist(), "affinity": _nan_none(Ap),
                "distance": _nan_none(r.distance), "distance_px": _nan_none(r.distance_px, 2),
                "shared_landmarks": r.shared_landmarks.tolist(), "shared_frames": r.shared_frames.tolist(),
                "source": source}
            view_pairs.append((a, b))

    def describe(i: int) -> list:
        return [names[nodes[i].view], nodes[i].track]

    grouping = group_tracks(nodes, A, evidence, view_pairs, s.min_affinity, s.coexist_tolerance, describe)
    # persons ordered by number of views, then frames
    def key(g):
        return (-len({nodes[i].view for i in g}), -sum(int(nodes[i].presence.sum()) for i in g), g[0])

    groups = sorted(grouping.groups, key=key)
    assignments: dict[str, dict[int, int]] = {n: {} for n in names}
    for pid, g in enumerate(groups):
        for i in g:
            assignments[names[nodes[i].view]][nodes[i].track] = pid
    frames = {(names[n.view], n.track): int(n.presence.sum()) for n in nodes}
    # why pairs of evidence-sharing tracks were kept apart, for the diagnostics
    gid = {i: pid for pid, g in enumerate(groups) for i in g}
    n_multi = sum(1 for g in groups if len({nodes[i].view for i in g}) > 1)
    diag = {
        "persons": len(groups), "persons_multiview": n_multi, "tracks": N,
        "view_counts": {str(pid): len({nodes[i].view for i in g}) for pid, g in enumerate(groups)},
        "accepted_edges": len(grouping.edges), "rejected": len(grouping.rejected),
        "group_affinity": {str(pid): _mean_within(A, evidence, g) for pid, g in enumerate(groups)},
        "max_affinity_between_groups": _max_between(A, evidence, gid),
    }
    return Identities(names, assignments, pairs, grouping.rejected, unassigned, asdict(s), diag, {}, frames)


def _more_reliable(lm, kp, s: MatchSettings):
    """Per track pair the distance of the less noisy source on this camera pair where it has
    evidence, else the other's (see the module doc). -> (PairResult, "landmarks" | "keypoints")."""
    from mamma_kit.matching.pairs import PairResult

    ev_lm = (lm.shared_landmarks >= s.min_landmarks) & (lm.shared_frames >= 1)
    ev_kp = (kp.shared_landmarks >= s.min_landmarks) & (kp.shared_frames >= 1)
    kp_first = source_noise(kp.distance, ev_kp) < source_noise(lm.distance, ev_lm)
    first, second, ev1 = (kp, lm, ev_kp) if kp_first else (lm, kp, ev_lm)
    out = PairResult(*(np.where(ev1, getattr(first, f), getattr(second, f))
                       for f in ("distance", "distance_px", "shared_landmarks", "shared_frames")))
    return out, "keypoints" if kp_first else "landmarks"


def _mean_within(A, evidence, g) -> float | None:
    g = np.asarray(g)
    ev = evidence[np.ix_(g, g)]
    return round(float(A[np.ix_(g, g)][ev].mean()), 4) if ev.any() else None


def _max_between(A, evidence, gid: dict[int, int]) -> float:
    idx = np.array(sorted(gid))
    if len(idx) < 2:
        return 0.0
    lab = np.array([gid[i] for i in idx])
    diff = lab[:, None] != lab[None]
    vals = A[np.ix_(idx, idx)][diff & evidence[np.ix_(idx, idx)]]
    return round(float(vals.max()), 4) if len(vals) else 0.0


# ---- workspace entry point ------------------------------------------------------------
def camera_times(ws: Workspace, cams: list[str], tracks: dict, timing: Path | None) \
        -> tuple[dict[str, np.ndarray], str]:
    """Reference times of every camera's frames and how they were found (``tracks``: camera ->
    its track file's frame times, or anything with ``frame_times``)."""
    frame_times = {c: np.asarray(getattr(tracks[c], "frame_times", tracks[c]), np.float64) for c in cams}
    if timing is not None:
        from mamma_kit.core.timingfile import read_timing

        clocks, _ = read_timing(timing)
        missing = [c for c in cams if c not in clocks]
        if missing:
            raise UserError(f"{timing.name} has no clock for {', '.join(missing)}",
                            "run `mamma-kit sync WORKSPACE` again with every camera")
        return {c: clocks[c].to_ref(frame_times[c]) for c in cams}, str(timing)
    log.warn("no timing.toml: pairing frames across cameras by frame index (run `mamma-kit sync` first "
             "for unsynchronised cameras)")
    return {c: np.arange(len(frame_times[c]), dtype=np.float64) for c in cams}, "frame index"


def workspace_views(ws: Workspace, cameras: list[str] | None = None, calibration: Path | None = None,
                    timing: Path | None = None, settings: MatchSettings | None = None) \
        -> tuple[list[ViewSource], list[ViewSource | None] | None, str]:
    """The workspace's views ready for matching, read from their files a window at a time: landmark
    tracks, keypoint tracks (None where a camera has none, or None for all) and how frames are
    paired in time."""
    from mamma_kit.core.trackrows import TrackFile
    from mamma_kit.core.tracks import LandmarkTracks

    calib = calibration or ws.calibration
    if not Path(calib).is_file():
        raise UserError(f"no calibration at {calib}", "run `mamma-kit calibrate WORKSPACE` (or pass --calibration)")
    rig, _ = read_calibration(calib)
    if cameras is None:
        cameras = ws.load_capture().camera_names if ws.capture_toml.is_file() else \
            sorted(p.stem for p in ws.landmarks_dir.glob("*.npz"))
    missing = [c for c in cameras if not ws.landmarks_file(c).is_file()]
    if missing:
        raise UserError(f"no landmarks for {', '.join(missing)} (landmarks/<cam>.npz)",
                        "run `mamma-kit landmarks WORKSPACE` first")
    not_cal = [c for c in cameras if c not in rig]
    if not_cal:
        raise UserError(f"{Path(calib).name} has no camera {', '.join(not_cal)}",
                        "calibrate every camera of the capture, or pass --cameras")
    if len(cameras) < 2:
        raise UserError("matching needs at least two cameras", "pass two or more with --cameras")
    files = {c: TrackFile(ws.landmarks_file(c), LandmarkTracks, "landmark file") for c in cameras}
    if timing is None and ws.timing.is_file():
        timing = ws.timing
    times, how = camera_times(ws, cameras, {c: f.frame_times for c, f in files.items()},
                              Path(timing) if timing else None)
    s = settings or MatchSettings()
    views = [ViewSource.from_file(files[c], _camera_for(rig[c], files[c].header["image_size"]), times[c],
                                  s.vis_threshold) for c in cameras]
    kp_views = keypoint_views(ws, cameras, files, rig, times, s) if s.use_keypoints else None
    return views, kp_views, how


def keypoint_views(ws: Workspace, cameras: list[str], files: dict, rig, times,
                   s: MatchSettings) -> list[ViewSource | None] | None:
    """The cameras' keypoint tracks where keypoints/<cam>.npz exists for the same tracks, else None
    (``files``: the cameras' landmark files, core.trackrows.TrackFile)."""
    from mamma_kit.core.trackrows import TrackFile
    from mamma_kit.core.tracks import KeypointTracks

    out = []
    for c in cameras:
        path = ws.keypoints_file(c)
        kf = TrackFile(path, KeypointTracks, "keypoint file") if path.is_file() else None
        same = kf is not None and np.array_equal(kf.track_ids, files[c].track_ids) and \
            kf.n_frames == files[c].n_frames
        out.append(ViewSource.from_file(kf, _camera_for(rig[c], kf.header["image_size"]), times[c], s.vis_threshold)
                   if same else None)
    return out if any(v is not None for v in out) else None


def _camera_for(cam, size_wh) -> "object":
    """The calibrated camera at the landmarks' image size (a resized video keeps its calibration
    up to scale); a different aspect ratio is a user error."""
    w, h = int(size_wh[0]), int(size_wh[1])
    if (w, h) == tuple(cam.size) or w <= 0 or h <= 0:
        return cam
    sx, sy = w / cam.size[0], h / cam.size[1]
    if abs(sx - sy) > 0.01 * max(sx, sy):
        raise UserError(f"camera {cam.name} is calibrated at {cam.size[0]}x{cam.size[1]} but its landmarks are "
                        f"{w}x{h} (another aspect ratio)", "calibrate with videos of the same size and orientation")
    return cam.scaled(sx, sy)
