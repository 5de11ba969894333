"""ChArUco detection in board videos, and finding out what board a video really shows.

Detections of one camera are dense arrays over its sampled frames: ``xy_fn2`` (F, N, 2)
pixel positions of the N chessboard corners with NaN where a corner was not found, and
``times_f`` (F,) the frames' timestamps on the camera's own clock, ``index_f`` (F,) their
frame numbers in the video and ``mirrored_f`` (F,) which views show the board's back side.

A board seen from behind (through thin paper, or the back of a double-sided print) is the
mirror image of its front, so no marker reads right and no chessboard corner is found.
Where markers are found but no corners, the horizontally flipped image is searched too; its
corners, mapped back to the stored image (x -> W - 1 - x) with their ids, are observations
of the same 3D corners seen from the other side and serve intrinsics and extrinsics alike.

Short or low-frame-rate videos are read whole (every frame); long ones are sampled at about
``max_fps`` frames per second of video. Large frames are
searched for markers at a reduced size, then OpenCV interpolates and refines the chessboard
corners at full resolution from the scaled-up markers, so 4K phone videos cost little more
than 1080p ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from mamma_kit.calibration.board import DICTIONARIES, BoardSpec
from mamma_kit.core.errors import UserError
from mamma_kit.core.log import track

MIN_CORNERS = 6  # a view needs this many corners to be used


@dataclass
class Detections:
    camera: str
    video: str
    size: tuple[int, int]  # width, height of the displayed frames (after the file's display rotation)
    times_f: np.ndarray  # (F,) camera-clock seconds of the sampled frames
    xy_fn2: np.ndarray  # (F, N, 2) corner pixels, NaN where not detected
    n_markers_f: np.ndarray  # (F,) ArUco markers found per sampled frame
    rotation_deg: int = 0  # clockwise turn from the stored frames to the displayed ones
    frame_step: int = 1
    extra: dict = field(default_factory=dict)
    index_f: np.ndarray | None = None  # (F,) frame numbers in the video (default: k * frame_step)
    mirrored_f: np.ndarray | None = None  # (F,) bool: the view shows the board's back side

    def __post_init__(self):
        F = len(self.times_f)
        if self.index_f is None:
            self.index_f = np.arange(F) * int(self.frame_step)
        if self.mirrored_f is None:
            self.mirrored_f = np.zeros(F, bool)
        self.index_f = np.asarray(self.index_f, int)
        self.mirrored_f = np.asarray(self.mirrored_f, bool)

    @property
    def n_corners_f(self) -> np.ndarray:
        return np.isfinite(self.xy_fn2[..., 0]).sum(1)

    def usable(self, spec: BoardSpec, min_corners: int = MIN_CORNERS) -> np.ndarray:
        """Frame indices with enough corners spanning at least two rows and two columns."""
        ok = self.n_corners_f >= min_corners
        n = spec.squares_x - 1
        ids = np.arange(spec.n_corners)
        col, row = ids % n, ids // n
        seen = np.isfinite(self.xy_fn2[..., 0])
        # number of distinct columns / rows among the seen corners (vectorised over frames)
        cols = (seen[:, :, None] & (col[None, :, None] == np.arange(n)[None, None])).any(1).sum(1)
        rows = (seen[:, :, None] & (row[None, :, None] == np.arange(spec.squares_y - 1)[None, None])).any(1).sum(1)
        return np.nonzero(ok & (cols >= 2) & (rows >= 2))[0]

    def to_npz_dict(self) -> dict:
        return {"times_f": self.times_f, "xy_fn2": self.xy_fn2, "n_markers_f": self.n_markers_f,
                "size": np.array(self.size), "rotation_deg": np.array(self.rotation_deg),
                "frame_step": np.array(self.frame_step), "index_f": self.index_f, "mirrored_f": self.mirrored_f}

    @classmethod
    def from_npz_dict(cls, camera: str, video: str, z) -> "Detections":
        return cls(camera, video, tuple(int(v) for v in z["size"]), z["times_f"], z["xy_fn2"], z["n_markers_f"],
                   int(z["rotation_deg"]), int(z["frame_step"]), index_f=z["index_f"], mirrored_f=z["mirrored_f"])


class BoardFinder:
    """Detects one board spec in grey images; marker search on a reduced image when large."""

    def __init__(self, spec: BoardSpec, max_detect_width: int = 2000, inverted: bool | None = None,
                 mirrored: bool = True):
        self.spec = spec
        self.detector = spec.detector(inverted=inverted)
        self.max_w = int(max_detect_width)
        self.mirrored = bool(mirrored)

    def detect_any_side(self, grey: np.ndarray) -> tuple[np.ndarray, int, bool]:
        """-> (xy_n2, markers found, seen from behind): the front first; where markers are
        found but too few corners, the mirrored image, its corners mapped back to ``grey``'s
        pixels (x -> W - 1 - x) under their own ids."""
        xy, n_markers = self.detect(grey)
        if not self.mirrored or n_markers == 0 or np.isfinite(xy[:, 0]).sum() >= MIN_CORNERS:
            return xy, n_markers, False
        xy_m, n_m = self.detect(np.ascontiguousarray(grey[:, ::-1]))
        if np.isfinite(xy_m[:, 0]).sum() < max(MIN_CORNERS, np.isfinite(xy[:, 0]).sum() + 1):
            return xy, n_markers, False
        xy_m[:, 0] = grey.shape[1] - 1 - xy_m[:, 0]
        return xy_m, n_m, True

    def detect(self, grey: np.ndarray) -> tuple[np.ndarray, int]:
        """-> (xy_n2 with NaN rows for missing corners, number of markers found)."""
        n = self.spec.n_corners
        out = np.full((n, 2), np.nan)
        h, w = grey.shape[:2]
        scale = 1.0
        img = grey
        if max(w, h) > self.max_w:
            scale = self.max_w / max(w, h)
            img = cv2.resize(grey, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
        cc, ci, mc, mi = self.detector.detectBoard(img)
        n_markers = 0 if mi is None else len(mi)
        if ci is None or len(ci) == 0:
            return out, n_markers
        if scale != 1.0:
            # markers found small, chessboard corners interpolated and refined by OpenCV at full
            # resolution from the scaled-up markers (0.07 px on 4K renders, vs 0.11 px for a
            # cornerSubPix of upscaled corners, at the cost of the small search)
            mc_full = tuple(((np.asarray(m, np.float64).reshape(1, 4, 2) + 0.5) / scale - 0.5).astype(np.float32)
                            for m in mc)
            cc, ci, _, _ = self.detector.detectBoard(grey, markerCorners=mc_full, markerIds=mi)
            if ci is None or len(ci) == 0:
                return out, n_markers
        ids = ci.ravel().astype(int)
        xy = cc.reshape(-1, 2).astype(np.float64)
        keep = (ids >= 0) & (ids < n)
        ids, xy = ids[keep], xy[keep]
        keep = self._consistent(ids, xy)
        out[ids[keep]] = xy[keep]
        return out, n_markers

    def _consistent(self, ids: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Corners that agree with the board's geometry (a homography, with a tolerance of a
        quarter square for lens distortion); a frame that mostly disagrees (a board
        detected with the wrong layout) keeps none."""
        keep = np.ones(len(ids), bool)
        if len(ids) < 6:
            return keep
        obj = self.spec.corners_b3[ids, :2]
        d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        thr = max(3.0, 0.25 * float(np.median(d.min(1))))
        H, inl = cv2.findHomography(obj, xy, cv2.RANSAC, thr)
        if H is None or inl is None:
            return np.zeros(len(ids), bool)
        inl = inl.ravel().astype(bool)
        return inl if inl.mean() >= 0.7 else np.zeros(len(ids), bool)


WHOLE_VIDEO_FRAMES = 400  # videos with at most this many frames are read whole


def frame_step_for(nominal_fps: float, max_fps: float | None, n_frames: int | None = None) -> int:
    """Every ``step``-th frame is searched: about ``max_fps`` per second of video, but every
    frame of a short video (``n_frames`` <= WHOLE_VIDEO_FRAMES) and never fewer than that
    many frames of a longer one (a 20 s clip at 30 fps keeps every second frame)."""
    if not max_fps or max_fps <= 0 or nominal_fps <= 0:
        return 1
    step = max(1, int(round(nominal_fps / max_fps)))
    if n_frames is not None:
        step = max(1, min(step, int(n_frames) // WHOLE_VIDEO_FRAMES))
    return step


def detect_video(path: str | Path, spec: BoardSpec, camera: str | None = None, *, max_fps: float | None = 10.0,
                 max_detect_width: int = 2000, progress: bool = True, mirrored: bool = True,
                 rotation: int | None = None) -> Detections:
    """Detect the board in every ``step``-th frame of a video (see :func:`frame_step_for`),
    from the front or, with ``mirrored``, from behind; in the displayed frames (``rotation``:
    capture.toml's override of the file's display rotation)."""
    from mamma_kit.video.reader import VideoReader

    path = Path(path)
    r = VideoReader(path, rotation)
    info = r.info
    step = frame_step_for(info.nominal_fps, max_fps, info.n_frames)
    finder = BoardFinder(spec, max_detect_width, mirrored=mirrored)
    n_sel = (info.n_frames + step - 1) // step
    times = np.full(n_sel, np.nan)
    index = np.zeros(n_sel, int)
    xy = np.full((n_sel, spec.n_corners, 2), np.nan)
    nm = np.zeros(n_sel, int)
    back = np.zeros(n_sel, bool)
    k = 0
    frames = r.frames(fmt="gray")
    it = track(frames, f"detect {camera or path.stem}", total=info.n_frames) if progress else frames
    for i, (t, grey) in enumerate(it):
        if i % step or k >= n_sel:
            continue
        times[k], index[k] = t, i
        xy[k], nm[k], back[k] = finder.detect_any_side(grey)
        k += 1
    keep = np.isfinite(times)
    return Detections(camera or path.stem, str(path), (info.width, info.height), times[keep], xy[keep], nm[keep],
                      info.rotation_deg, step, index_f=index[keep], mirrored_f=back[keep])


# ---- what board does the video show? ------------------------------------------------------
# dictionary families surveyed for a board that does not match its spec; the _100 sizes
# hold every id of boards up to 200 squares and identify ~5x faster than the _1000 ones
_FAMILIES = ["4X4_100", "5X5_100", "6X6_100", "7X7_100", "APRILTAG_16H5", "APRILTAG_25H9", "APRILTAG_36H10",
             "ARUCO_MIP_36H12"]
_FAMILIES_SLOW = ["ARUCO_ORIGINAL", "APRILTAG_36H11", "4X4_1000", "5X5_1000", "6X6_1000", "7X7_1000"]


def _sample_frames(path: Path, n: int, det: Detections | None = None, rotation: int | None = None) -> list[np.ndarray]:
    """Up to ``n`` grey frames: those where the detection found the most markers (the
    frames that show a board), else spread evenly over the video."""
    from mamma_kit.video.reader import VideoReader

    r = VideoReader(path, rotation)
    idx = np.unique(np.linspace(0, r.n_frames - 1, min(n, r.n_frames)).round().astype(int))
    if det is not None and len(det.n_markers_f) and det.n_markers_f.max() > 0:
        order = np.argsort(-det.n_markers_f, kind="stable")
        order = order[det.n_markers_f[order] > 0][:n]
        idx = np.unique(det.index_f[order])
    return [img for _, _, img in r.read_indices(idx, fmt="gray")]


def _smallest_dictionary(family: str, max_id: int) -> str:
    """The smallest predefined dictionary of a family that holds marker id ``max_id``."""
    base, _, size = family.rpartition("_")
    if size.isdigit() and base.count("X") == 1:
        for n in (50, 100, 250, 1000):
            if max_id < n:
                return f"DICT_{base}_{n}"
    return "DICT_" + family


def _count(fam: str, frames: list[np.ndarray], inverted: bool) -> tuple[int, list[int]]:
    d = cv2.aruco.getPredefinedDictionary(DICTIONARIES[fam])
    p = cv2.aruco.DetectorParameters()
    p.detectInvertedMarker = inverted
    det = cv2.aruco.ArucoDetector(d, p)
    n, ids = 0, []
    for g in frames:
        _, mi, _ = det.detectMarkers(g)
        if mi is not None:
            n += len(mi)
            ids += mi.ravel().tolist()
    return n, ids


def _marker_survey(frames: list[np.ndarray]) -> dict:
    """Markers per dictionary family over sample frames, and how many are inverted.

    Detection with ``detectInvertedMarker`` finds both polarities; one more pass without it
    for the best family tells them apart. The large (slow) dictionaries are tried only
    when the common ones find nothing."""
    res = {}
    for families in (_FAMILIES, _FAMILIES_SLOW):
        for fam in families:
            n, ids = _count(fam, frames, True)
            res[fam] = {"any": n, "ids": ids}
        if any(v["any"] for v in res.values()):
            break
    best = max(res, key=lambda f: res[f]["any"])
    if res[best]["any"]:
        n_norm, _ = _count(best, frames, False)
        res[best]["normal"] = n_norm
        res[best]["inverted"] = res[best]["any"] - n_norm
    return res


def _corner_score(spec: BoardSpec, frames: list[np.ndarray]) -> int:
    """Corners found over the frames that agree with a homography of the board (so a wrong
    layout that still yields some corners scores low)."""
    finder = BoardFinder(spec, mirrored=False)
    total = 0
    for g in frames:
        xy, _ = finder.detect(g)
        ok = np.isfinite(xy[:, 0])
        if ok.sum() < 4:
            continue
        obj = spec.corners_b3[ok, :2]
        H, inl = cv2.findHomography(obj, xy[ok], cv2.RANSAC, max(2.0, 0.01 * max(g.shape)))
        total += int(inl.sum()) if inl is not None else 0
    return total


def diagnose_board(path: str | Path, spec: BoardSpec, camera: str, n_frames: int = 12,
                   detections: Detections | None = None, rotation: int | None = None) -> UserError | None:
    """Find which board variant a video shows and return the UserError that says so, or
    None when the spec itself is the best match (the board is just seldom seen well).

    Looks at the frames where the detection found most markers (``detections``), else at
    frames spread over the video. Tries other dictionaries (by surveying markers of every
    family), the legacy layout, inverted colours, swapped rows/columns and the board seen
    from behind (mirrored), and names the variant that matches."""
    path = Path(path)
    frames = _sample_frames(path, n_frames, detections, rotation)
    where = f"camera {camera}: no ChArUco board found in {len(frames)} sampled frames of {path.name} " \
            f"(spec {spec.describe()})"
    mirrored = [np.ascontiguousarray(g[:, ::-1]) for g in frames]
    # markers of a board seen from behind read right only in the mirrored frames
    surveys = [_marker_survey(frames), _marker_survey(mirrored)]
    survey = max(surveys, key=lambda sv: max(v["any"] for v in sv.values()))
    fam = max(survey, key=lambda f: survey[f]["any"])
    info = survey[fam]
    n_found = info["any"]
    if n_found == 0:
        return UserError(f"{where}; no ArUco markers of any dictionary are visible",
                         "check that this video shows the board, in focus and close enough that a square spans "
                         "at least about 15 pixels")
    inverted = info["inverted"] > info["normal"]
    dictionary = _smallest_dictionary(fam, max(info["ids"]))
    # the spec's own dictionary holds the same first markers as others of its family
    spec_base = spec.dictionary.removeprefix("DICT_").rpartition("_")[0]
    if spec_base and spec_base == fam.rpartition("_")[0] and max(info["ids"]) < cv2.aruco.getPredefinedDictionary(
            DICTIONARIES[spec.dictionary[5:]]).bytesList.shape[0]:
        dictionary = spec.dictionary
    base = spec.with_(dictionary=dictionary, inverted=inverted)
    variants = []
    for back in (False, True):
        for swap in (False, True):
            for legacy in (False, True):
                v = base.with_(legacy=legacy)
                if swap:
                    v = v.with_(squares_x=spec.squares_y, squares_y=spec.squares_x)
                try:
                    variants.append((v, back, _corner_score(v, mirrored if back else frames)))
                except UserError:
                    continue
    best, from_behind, score = max(variants, key=lambda vs: vs[2])
    changes = []
    if best.dictionary != spec.dictionary:
        changes.append(f'dictionary = "{best.dictionary}"')
    if best.inverted != spec.inverted:
        changes.append(f"inverted = {'true' if best.inverted else 'false'}")
    if best.legacy != spec.legacy:
        changes.append(f"legacy = {'true' if best.legacy else 'false'}")
    if best.squares_x != spec.squares_x:
        changes.append(f"squares_x = {best.squares_x}, squares_y = {best.squares_y} (rows and columns swapped)")
    behind = " seen from behind (the board's back side, mirrored)" if from_behind and score > 0 else ""
    if not changes and score > 0:
        if behind and detections is not None:
            n_back = int(detections.mirrored_f.sum())
            return UserError(f"{where}; the board is{behind} in {n_back} frames, too few to calibrate this camera",
                             "record the board's front for this camera too, closer, at several places and tilts")
        return None  # the spec is right: the board is just rarely seen well
    if score == 0 or not changes:
        return UserError(f"{where}; {n_found} {fam} markers are visible but no variant of the board "
                         f"(dictionary, legacy layout, inverted, swapped rows/columns, seen from behind) yields "
                         f"chessboard corners",
                         "check squares_x, squares_y and the marker ids of the printed board, or print it again "
                         "with `mamma-kit board`")
    what = {"dictionary": "another dictionary", "inverted": "inverted colours", "legacy": "the legacy layout",
            "squares_x": "swapped rows/columns"}
    kinds = [what[c.split(" ")[0]] for c in changes]
    return UserError(f"{where}; the video shows a board with {', '.join(kinds)}{behind}: it matches "
                     f"{', '.join(changes)} ({score} corners found)",
                     f"set {'; '.join(changes)} in the board spec and run again")
