"""What the fit reads from a workspace, as arrays on the output frames.

Output frames: the frames of the reference camera (timing.toml's reference, else the first
selected camera) inside the reference-time interval that every selected camera covers,
on the reference clock. Each view's landmarks are taken at the output frame's exact
reference time: a camera frame exposed at camera time t was exposed at reference time
clock.to_ref(t), and the view's landmarks are interpolated linearly between its two frames
around the output time (sub-frame offsets compensated, not rounded). Where only one of the
two frames has the person, it is used if it lies within a quarter frame of the output time.

Arrays (C cameras, P people, T frames, L landmarks), camera-major:
xy (C, P, T, L, 2) px, sigma (C, P, T, L, 2) px, vis (C, P, T, L) visibility in [0, 1]
(0 where the view has no observation), contact and floor (C, P, T, L) probabilities,
present (C, P, T) bool.

Keypoints (keypoints/<cam>.npz, BlazePose's 33 points on the same track ids as the
landmarks, so identities.json maps them alike), taken at the output times the same way:
kp_xy (C, P, T, 33, 2) px, kp_vis (C, P, T, 33) visibility x presence (0 where the view has
none), kp_size (C, P, T) px the person's size in the view (the larger side of the box of
its 33 points: the scale of BlazePose's error). None when no selected camera has
keypoints; cameras without a file have kp_vis 0 (both said in notes). The hands read with them
(keypoints/hands.py), left then right, 21 points each: hand_xy (C, P, T, 42, 2) px, hand_vis
(C, P, T, 42) the hand model's flag where it is sure of the hand (> HAND_SURE_FLAG), else 0. Its
handedness is not used: on the real recording in shared/real/, hands whose handedness disagrees with
BlazePose's side are 3 times as often > 10 % of the box height off the other views, but dropping
them (a ramp from 0.2 to 0.8 agreement) made the held-out hands worse (benchmarks/heldout_view.py:
median 2.97 -> 3.07 %, PCK@5 74.0 -> 71.9 %): the fit's robust loss already sets the wrong ones aside.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mamma_kit.core import log
from mamma_kit.core.calibfile import read_calibration
from mamma_kit.core.camera import Rig
from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError
from mamma_kit.core.filled import fill_inputs, open_tracks
from mamma_kit.core.tracks import HAND_SURE_FLAG, N_HAND_POINTS
from mamma_kit.core.workspace import Workspace

NEAR_FRAC = 0.25  # use a lone neighbouring frame when within this fraction of a frame interval
MIN_SIGMA = 0.25  # px: the fit divides by sigma


@dataclass
class FitData:
    rig: Rig
    clocks: dict[str, ClockModel]
    reference: str  # the clock the frame times are on (a camera name, or e.g. "scene")
    frame_camera: str  # whose frames the output frames are
    frame_times: np.ndarray  # (T,) reference clock
    fps: float
    person_ids: list[int]
    xy: np.ndarray
    sigma: np.ndarray
    vis: np.ndarray
    contact: np.ndarray
    floor: np.ndarray
    present: np.ndarray
    landmark_set: str = ""
    notes: list[str] = field(default_factory=list)
    inputs: list[Path] = field(default_factory=list)
    kp_xy: np.ndarray | None = None
    kp_vis: np.ndarray | None = None
    kp_size: np.ndarray | None = None
    hand_xy: np.ndarray | None = None
    hand_vis: np.ndarray | None = None

    @property
    def has_hands(self) -> bool:
        return self.hand_vis is not None and bool((self.hand_vis > 0).any())

    @property
    def has_keypoints(self) -> bool:
        return self.kp_vis is not None and bool((self.kp_vis > 0).any())

    @property
    def cameras(self) -> list[str]:
        return self.rig.names

    @property
    def shape(self) -> tuple[int, int, int, int]:
        C, P, T, L = self.vis.shape
        return C, P, T, L

    def slice_frames(self, s: slice) -> "FitData":
        """The same data over a range of output frames (a chunk)."""
        sub = lambda a: None if a is None else a[:, :, s]  # noqa: E731
        return FitData(self.rig, self.clocks, self.reference, self.frame_camera, self.frame_times[s], self.fps,
                       self.person_ids, sub(self.xy), sub(self.sigma), sub(self.vis), sub(self.contact),
                       sub(self.floor), sub(self.present), self.landmark_set, self.notes, self.inputs,
                       sub(self.kp_xy), sub(self.kp_vis), sub(self.kp_size), sub(self.hand_xy), sub(self.hand_vis))


class LandmarkReader:
    """The cameras' landmark files read into the fit's arrays for some output frames: each view's
    tracks sampled at the output times (module doc), a block of frames at a time. The files stay open
    between calls (frames asked for in increasing order are read in one pass); pickled without them."""

    def __init__(self, root: Path, names: list[str], ref_times: dict, person_of: dict, pindex: dict, n: int):
        self.root, self.names, self.ref_times, self.person_of = Path(root), names, ref_times, person_of
        self.pindex, self.n = pindex, n
        self._files: dict | None = None

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_files": None}

    def read(self, out_t: np.ndarray) -> tuple[np.ndarray, ...]:
        """xy, sigma, vis, contact, floor at the output times ``out_t`` (module doc's arrays)."""
        ws = Workspace(self.root)
        if self._files is None:
            self._files = {n: open_tracks(ws, "landmarks", n) for n in self.names}
        C, P, T, L = len(self.names), len(self.pindex), len(out_t), self.n
        xy = np.zeros((C, P, T, L, 2), np.float32)
        sigma = np.ones((C, P, T, L, 2), np.float32)
        vis = np.zeros((C, P, T, L), np.float32)
        contact = np.zeros((C, P, T, L), np.float32)
        floor = np.zeros((C, P, T, L), np.float32)
        taken = np.zeros((C, P, T), bool)
        keys = ("valid", "xy", "sigma", "visibility", "contact", "floor_contact")
        for ci, n in enumerate(self.names):
            if not len(self.ref_times[n]):
                continue
            for pi, take, mix, lt in sample_camera(self._files[n], self.ref_times[n], out_t, self.person_of[n],
                                                   self.pindex, taken[ci], keys):
                xy_m = mix(lt["xy"])
                bad = ~np.isfinite(xy_m).all(-1)
                xy[ci, pi, take] = np.nan_to_num(xy_m)
                sigma[ci, pi, take] = np.maximum(np.nan_to_num(mix(lt["sigma"]), nan=1e3), MIN_SIGMA)
                vv = np.clip(np.nan_to_num(mix(lt["visibility"])), 0, 1)
                vv[bad] = 0.0
                vis[ci, pi, take] = vv
                contact[ci, pi, take] = np.clip(np.nan_to_num(mix(lt["contact"])), 0, 1)
                floor[ci, pi, take] = np.clip(np.nan_to_num(mix(lt["floor_contact"])), 0, 1)
                taken[ci, pi, take] = True
        return xy, sigma, vis, contact, floor

    def close(self) -> None:
        for cf in (self._files or {}).values():
            cf.close()
        self._files = None


@dataclass
class FitSource(FitData):
    """FitData whose landmark arrays (xy, sigma, vis, contact, floor: None here) stay in their files
    until ``slice_frames`` asks for some frames: the fit holds a chunk's landmarks, not the take's.
    Everything else (present, keypoints, hands) is the take's, as in FitData."""

    landmarks: LandmarkReader | None = None

    @property
    def shape(self) -> tuple[int, int, int, int]:
        C, P, T = self.present.shape
        return C, P, T, self.landmarks.n

    def slice_frames(self, s) -> FitData:
        """FitData of the output frames ``s`` (a slice or indices), their landmarks read from the files."""
        idx = np.arange(len(self.frame_times))[s]
        xy, sigma, vis, contact, floor = self.landmarks.read(self.frame_times[idx])
        sub = lambda a: None if a is None else a[:, :, idx]  # noqa: E731
        return FitData(self.rig, self.clocks, self.reference, self.frame_camera, self.frame_times[idx], self.fps,
                       self.person_ids, xy, sigma, vis, contact, floor, sub(self.present), self.landmark_set,
                       self.notes, self.inputs, sub(self.kp_xy), sub(self.kp_vis), sub(self.kp_size),
                       sub(self.hand_xy), sub(self.hand_vis))


def _read_clocks(ws: Workspace, names: list[str]) -> tuple[dict[str, ClockModel], str, list[str]]:
    notes = []
    if ws.timing.is_file():
        from mamma_kit.core.timingfile import read_timing

        clocks, info = read_timing(ws.timing)
        missing = [n for n in names if n not in clocks]
        if missing:
            raise UserError(f"timing.toml has no clock for {', '.join(missing)}",
                            "run `mamma-kit sync WORKSPACE` again with these cameras")
        ref = str(info.get("reference") or names[0])
        return {n: clocks[n] for n in names}, ref, notes
    notes.append("no timing.toml: cameras assumed synchronised (identity clocks)")
    log.warn(notes[-1] + "; run `mamma-kit sync` for unsynchronised cameras")
    return {n: ClockModel() for n in names}, names[0], notes


class PersonMap:
    """Which person each view's track shows at each of its frames: identities.json (a track may
    show different people in different stretches), else each track id is its person id."""

    def __init__(self, ws: Workspace):
        from mamma_kit.core.filled import load_identities

        # the match's identities, with the tracks `mamma-kit fill` added where it ran on them
        self.ident = load_identities(ws) if ws.identities.is_file() else None
        self.notes: list[str] = []
        if self.ident is None:
            self.notes.append("no identities.json: each view's track id is taken as the person id")
            log.info("fit: " + self.notes[-1] + " (true for ground-truth landmarks; run `mamma-kit match` otherwise)")

    def frames(self, camera: str, track_ids: np.ndarray, times_ref: np.ndarray) -> np.ndarray:
        """(T, K) person id of each track at each frame, -1 for none."""
        if self.ident is None:
            return np.broadcast_to(np.asarray(track_ids, np.int64), (len(times_ref), len(track_ids))).copy()
        return self.ident.person_frames(camera, track_ids, times_ref)


def _bracket(tr: np.ndarray, out_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A view's frames around each output time: i0, i1 (T,) and the fraction a of the way."""
    i0 = np.clip(np.searchsorted(tr, out_t, side="right") - 1, 0, max(len(tr) - 2, 0))
    i1 = np.minimum(i0 + 1, len(tr) - 1)
    span = np.where(i1 > i0, tr[i1] - tr[i0], 1.0)
    return i0, i1, np.clip((out_t - tr[i0]) / span, 0.0, 1.0)


def _sampling(ok: np.ndarray, i0: np.ndarray, i1: np.ndarray, a: np.ndarray, taken: np.ndarray):
    """Output frames a track covers (both neighbours, or one within NEAR_FRAC) and not yet
    ``taken`` by another track of the person: take (T,), and the frames f0, f1 and weight
    w1 (n,) to mix. None if it covers nothing."""
    v0, v1 = ok[i0], ok[i1]
    both = v0 & v1
    use0 = ~both & v0 & (a <= NEAR_FRAC)
    use1 = ~both & v1 & (a >= 1 - NEAR_FRAC)
    w1 = np.where(both, a, np.where(use1, 1.0, 0.0))
    take = (both | use0 | use1) & ~taken  # a person's first track wins a frame
    if not take.any():
        return None
    return take, i0[take], i1[take], w1[take]


def _mixer(f0: np.ndarray, f1: np.ndarray, w1: np.ndarray, k: int):
    """Linear mix of a track column's values at frames f0, f1 (NaN-tolerant)."""
    def mix(arr):
        a0, a1 = arr[f0, k].astype(np.float64), arr[f1, k].astype(np.float64)
        a0 = np.where(np.isfinite(a0), a0, a1)
        a1 = np.where(np.isfinite(a1), a1, a0)
        w = w1.reshape(w1.shape + (1,) * (a0.ndim - 1))
        return (1 - w) * a0 + w * a1
    return mix


def sampled_tracks(valid_tk: np.ndarray, person_tk: np.ndarray, pindex: dict, i0, i1, a, taken_pt: np.ndarray):
    """For each stretch of a view's tracks showing a fitted person (person_tk (T, K), -1 none):
    (pi, take (T,), mix), where ``mix(arr)`` samples that track's column of a (frames, tracks, ...)
    array at the output frames ``take`` (see _sampling); a person's first track wins a frame
    (taken_pt (P, T))."""
    for k in range(person_tk.shape[1]):
        for p in np.unique(person_tk[:, k][person_tk[:, k] >= 0]):
            if int(p) not in pindex:  # a person left out (seen in one view)
                continue
            pi = pindex[int(p)]
            smp = _sampling(valid_tk[:, k] & (person_tk[:, k] == p), i0, i1, a, taken_pt[pi])
            if smp is None:
                continue
            take, f0, f1, w1 = smp
            yield pi, take, _mixer(f0, f1, w1, k)


SAMPLE_BLOCK = 256  # output frames whose views' rows are read at once (memory: their window, not the take)


def sample_camera(cf, tr: np.ndarray, out_t: np.ndarray, person_tk: np.ndarray, pindex: dict,
                  taken_pt: np.ndarray, keys: tuple[str, ...]):
    """``sampled_tracks`` over a camera's files (core.filled.CameraTracks) a block of output frames at a time (SAMPLE_BLOCK):
    yields (pi, frames (n,) output frame indices, mix, arrays) where ``mix(arrays[key])`` gives that
    stretch's values at those frames. ``tr``: the camera's frame times on the reference clock;
    ``taken_pt`` (P, T): output frames a person already has from this camera (updated by the caller)."""
    i0, i1, a = _bracket(tr, out_t)
    starts = [0]  # blocks of output frames whose view frames lie within SAMPLE_BLOCK of each other
    for j in range(1, len(out_t)):
        if j - starts[-1] >= SAMPLE_BLOCK or abs(int(i1[j]) - int(i0[starts[-1]])) >= SAMPLE_BLOCK:
            starts.append(j)
    for o0, o1 in zip(starts, starts[1:] + [len(out_t)]):
        lo, hi = int(min(i0[o0:o1].min(), i1[o0:o1].min())), int(max(i0[o0:o1].max(), i1[o0:o1].max())) + 1
        cols, arrays = cf.window(lo, hi, keys)
        if not len(cols):
            continue
        for pi, take, mix in sampled_tracks(arrays["valid"], person_tk[lo:hi, cols], pindex, i0[o0:o1] - lo,
                                            i1[o0:o1] - lo, a[o0:o1], taken_pt[:, o0:o1]):
            yield pi, o0 + np.flatnonzero(take), mix, arrays


def point_box_size(xy_tk_n2: np.ndarray) -> np.ndarray:
    """Larger side (px) of the box around each detection's points: (..., n, 2) -> (...)."""
    with warnings.catch_warnings():  # rows without any point are NaN (then 0): no warning for them
        warnings.simplefilter("ignore", RuntimeWarning)
        ext = np.nanmax(xy_tk_n2, -2) - np.nanmin(xy_tk_n2, -2)
    return np.nan_to_num(ext.max(-1), nan=0.0)


def load_keypoints(ws: Workspace, names: list[str], ref_times: dict, out_t: np.ndarray, pmap: PersonMap,
                   pindex: dict, image_sizes: dict) -> tuple[np.ndarray | None, ...]:
    """kp_xy, kp_vis, kp_size, hand_xy, hand_vis (module doc) and the files read; Nones without
    any file. Each camera's file is read a block of frames at a time (sample_camera)."""
    have = [n for n in names if ws.keypoints_file(n).is_file()]
    if not have:
        return None, None, None, None, None, []
    C, P, T = len(names), len(pindex), len(out_t)
    kp_xy = np.zeros((C, P, T, 33, 2), np.float32)
    kp_vis = np.zeros((C, P, T, 33), np.float32)
    kp_size = np.zeros((C, P, T), np.float32)
    H = 2 * N_HAND_POINTS  # left hand, then right
    hand_xy = np.zeros((C, P, T, H, 2), np.float32)
    hand_vis = np.zeros((C, P, T, H), np.float32)
    taken = np.zeros((C, P, T), bool)
    keys = ("valid", "xy", "visibility", "presence", "hand_xy", "hand_presence")
    for ci, n in enumerate(names):
        if n not in have:
            continue
        cf = open_tracks(ws, "keypoints", n)
        if tuple(cf.image_size) != tuple(image_sizes[n]):
            raise UserError(f"keypoints/{n}.npz is for {cf.image_size[0]}x{cf.image_size[1]} images, "
                            f"calibration.toml says {image_sizes[n][0]}x{image_sizes[n][1]}",
                            "run `mamma-kit keypoints` on the calibrated videos (--force)")
        if cf.n != 33:
            raise UserError(f"keypoints/{n}.npz holds {cf.n} points per person, the fit expects 33",
                            "run `mamma-kit keypoints WORKSPACE --force`")
        tr = ref_times[n](cf.frame_times)
        if len(tr) == 0:
            continue
        person_tk = pmap.frames(n, cf.track_ids, tr)
        for pi, take, mix, kt in sample_camera(cf, tr, out_t, person_tk, pindex, taken[ci], keys):
            if "size" not in kt:  # the box of each detection's points, once per block's window
                kt["size"] = point_box_size(kt["xy"])
            xy_m = mix(kt["xy"])
            bad = ~np.isfinite(xy_m).all(-1)
            vv = np.clip(np.nan_to_num(mix(kt["visibility"]) * mix(kt["presence"])), 0, 1)
            vv[bad] = 0.0
            kp_xy[ci, pi, take] = np.nan_to_num(xy_m)
            kp_vis[ci, pi, take] = vv
            kp_size[ci, pi, take] = mix(kt["size"])
            taken[ci, pi, take] = True
            # an unsure frame counts as a flag of -1 in the mix: a hand between a sure and an unsure
            # frame keeps a weight only when it is mostly the sure one's
            h_xy = mix(kt["hand_xy"]).reshape(-1, H, 2)
            flag = mix(np.where(kt["hand_presence"] > HAND_SURE_FLAG, kt["hand_presence"], -1.0))  # (n, 2)
            hv = np.repeat(np.clip(flag, 0, 1), N_HAND_POINTS, axis=-1)
            hv[~np.isfinite(h_xy).all(-1)] = 0.0
            hand_xy[ci, pi, take] = np.nan_to_num(h_xy)
            hand_vis[ci, pi, take] = hv
        cf.close()
    return kp_xy, kp_vis, kp_size, hand_xy, hand_vis, [ws.keypoints_file(n) for n in have]


def select_cameras(rig: Rig, cameras: int | None, camera_list: list[str] | None) -> list[str]:
    if camera_list:
        bad = [c for c in camera_list if c not in rig]
        if bad:
            raise UserError(f"camera(s) {', '.join(bad)} not in calibration.toml",
                            f"cameras: {', '.join(rig.names)}")
        return list(dict.fromkeys(camera_list))
    if cameras is not None:
        from mamma_kit.fitting.cameras import pick_cameras

        return pick_cameras(rig, cameras)
    return rig.names


def open_fit_data(ws: Workspace, cameras: int | None = None, camera_list: list[str] | None = None,
                  n_landmarks: int | None = None, keypoints: bool = True) -> "FitSource":
    """Read calibration, timing, keypoints (unless ``keypoints`` is False) and identities of a
    workspace, and where its landmarks are (see module doc): a FitSource, whose slice_frames reads
    the landmarks of the frames asked for."""
    if not ws.calibration.is_file():
        raise UserError(f"{ws.root} has no calibration.toml", "run `mamma-kit calibrate WORKSPACE` first")
    rig_all, _ = read_calibration(ws.calibration)
    have = [n for n in rig_all.names if ws.landmarks_file(n).is_file()]
    if not have:
        raise UserError(f"{ws.root} has no landmarks (landmarks/<cam>.npz)", "run `mamma-kit landmarks WORKSPACE` first")
    if camera_list:
        missing = [c for c in camera_list if c in rig_all and not ws.landmarks_file(c).is_file()]
        if missing:
            raise UserError(f"no landmarks for {', '.join(missing)}", "run `mamma-kit landmarks` for them")
    names = select_cameras(rig_all.subset(have), cameras, camera_list)
    if len(names) < 2:
        log.warn(f"fitting from {len(names)} camera: depth comes only from the body model")
    rig = rig_all.subset(names)
    clocks, reference, notes = _read_clocks(ws, names)
    tracks = {n: open_tracks(ws, "landmarks", n) for n in names}
    L = {lt.n for lt in tracks.values()}
    if len(L) != 1 or (n_landmarks is not None and L != {n_landmarks}):
        raise UserError(f"landmark files hold {sorted(L)} landmarks, the body model has {n_landmarks}",
                        "run `mamma-kit landmarks` with weights made for this body model's landmark set")
    L = L.pop()
    for n, lt in tracks.items():
        if tuple(lt.image_size) != tuple(rig[n].size):
            raise UserError(f"landmarks/{n}.npz is for {lt.image_size[0]}x{lt.image_size[1]} images, "
                            f"calibration.toml says {rig[n].size[0]}x{rig[n].size[1]}",
                            "calibrate and run landmarks on the same videos")
    pmap = PersonMap(ws)
    notes += pmap.notes
    ref_times = {n: clocks[n].to_ref(tracks[n].frame_times) for n in names}
    person_of = {n: pmap.frames(n, tracks[n].track_ids, ref_times[n]) for n in names}
    views_of: dict[int, set] = {}
    for cam, person_tk in person_of.items():
        for p in np.unique(person_tk[(person_tk >= 0) & tracks[cam].valid_tk()]):
            views_of.setdefault(int(p), set()).add(cam)
    # one view leaves a body's depth to the shape prior alone: not a multi-view fit
    single = sorted(p for p, v in views_of.items() if len(v) < 2) if len(names) > 1 else []
    if single:
        notes.append(f"person(s) {', '.join(map(str, single))} matched in one view only: not fitted")
    person_ids = sorted(p for p in views_of if p not in single)
    if not person_ids:
        raise UserError("no person is matched in two or more views" if single else "no person is matched in any view",
                        "check identities.json and report/match/affinities.png (`mamma-kit match`): the landmarks "
                        "or the calibration may be off")

    frame_camera = reference if reference in names else names[0]
    lo = max(float(t[0]) for t in ref_times.values() if len(t))
    hi = min(float(t[-1]) for t in ref_times.values() if len(t))
    ft = ref_times[frame_camera]
    eps = 1e-6
    out_t = ft[(ft >= lo - eps) & (ft <= hi + eps)]
    if len(out_t) < 1:
        raise UserError("the cameras' recordings do not overlap in time", "check timing.toml (`mamma-kit sync`)")
    d = np.diff(ft)
    fps = float(1.0 / np.median(d)) if len(d) else 30.0

    C, P, T = len(names), len(person_ids), len(out_t)
    pindex = {p: i for i, p in enumerate(person_ids)}
    # where each view shows each person at the output frames: from the files' valid flags only
    present = np.zeros((C, P, T), bool)
    for ci, n in enumerate(names):
        if len(ref_times[n]):
            for pi, take, _, _ in sample_camera(tracks[n], ref_times[n], out_t, person_of[n], pindex, present[ci],
                                                ("valid",)):
                present[ci, pi, take] = True
        tracks[n].close()
    sets = {str(lt.files[0].header.get("landmark_set", "")) for lt in tracks.values()}
    inputs = [ws.calibration] + [ws.landmarks_file(n) for n in names]
    inputs += [p for p in (ws.timing, ws.identities) if p.is_file()] + fill_inputs(ws, names)
    kp_xy = kp_vis = kp_size = hand_xy = hand_vis = None
    if keypoints:
        kp_xy, kp_vis, kp_size, hand_xy, hand_vis, kp_files = load_keypoints(
            ws, names, {n: clocks[n].to_ref for n in names}, out_t, pmap, pindex, {n: rig[n].size for n in names})
        inputs += kp_files
        if not kp_files:
            notes.append("no keypoints/<cam>.npz: the keypoint energy is off (run `mamma-kit keypoints`)")
        elif len(kp_files) < len(names):
            notes.append("no keypoints for " + ", ".join(n for n in names if not ws.keypoints_file(n).is_file())
                         + ": the keypoint energy uses the other views")
    return FitSource(rig, clocks, reference, frame_camera, out_t, fps, person_ids, None, None, None, None, None,
                     present, ",".join(sorted(s for s in sets if s)), notes, inputs, kp_xy, kp_vis, kp_size,
                     hand_xy, hand_vis, landmarks=LandmarkReader(ws.root, names, ref_times, person_of, pindex, L))


def load_fit_data(ws: Workspace, cameras: int | None = None, camera_list: list[str] | None = None,
                  n_landmarks: int | None = None, keypoints: bool = True) -> FitData:
    """Everything the fit reads of a workspace, the landmarks of every frame in memory (open_fit_data
    reads them a chunk at a time)."""
    return open_fit_data(ws, cameras, camera_list, n_landmarks, keypoints).slice_frames(slice(None))
