"""Synthetic ChArUco board sessions: board trajectories and realistic board videos.

A session is what a person does with a printed board in front of a rig: carry it through
the capture volume and hold it still for about a second at each place, turned towards a
pair of neighbouring cameras (shared views for extrinsics); bring it close to each camera
and hold it at several places and tilts (close-ups for intrinsics); finally lay it flat on
the floor: at a couple of places, and last at the world origin (the world frame: Z up, floor
z = 0; the boards away from the origin pin the floor plane over a wide baseline).

Rendering is by inverse mapping through the real lens model: for each output pixel (and
``supersample`` x ``supersample`` sub-pixel samples) the ray is found by undistorting the
pixel (exactly, vectorised), intersected with the board plane, and the board texture is
looked up at the right level of a pyramid (anti-aliasing), over a textured background,
with lighting, vignetting, sensor noise, optional motion blur (exposure sampled in time)
and H.264 compression. Boards partly out of view and seen from the back happen naturally.

The floor board lies face up with its origin at the world origin: board x = world X,
board y = world -Y, board z = world -Z (OpenCV board z points into the board), so a
calibration that pins the world frame to the floor board reproduces the synthetic world
frame exactly and results compare without any alignment.

Entry point for the synthetic-capture generator: :func:`render_board_session`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from mamma_kit.calibration.board import BoardSpec
from mamma_kit.calibration.lens import undistort_exact
from mamma_kit.core.camera import Camera, Rig
from mamma_kit.core.clock import ClockModel
from mamma_kit.core.log import track

# face-up floor board -> world: x_w = x_b, y_w = -y_b, z_w = -z_b
R_WORLD_FLOOR_BOARD = np.diag([1.0, -1.0, -1.0])


def ray_map(cam: Camera, pad: int = 1) -> np.ndarray:
    """Undistorted normalised coordinates of every pixel centre, (H + 2 pad, W + 2 pad, 2)
    float32; entry [pad + v, pad + u] belongs to pixel (u, v)."""
    w, h = cam.size
    vv, uu = np.mgrid[-pad:h + pad, -pad:w + pad]
    xy = np.stack([uu.ravel(), vv.ravel()], -1).astype(np.float64)
    out = np.empty((len(xy), 2), np.float32)
    step = 1 << 18
    for k in range(0, len(xy), step):
        out[k:k + step] = undistort_exact(cam, xy[k:k + step])
    return out.reshape(h + 2 * pad, w + 2 * pad, 2)


# ---- trajectories -------------------------------------------------------------------------
def _min_jerk(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10 - 15 * s + 6 * s * s)


@dataclass
class BoardTrajectory:
    """Board-to-world pose over reference time: holds joined by minimum-jerk moves.

    ``R_wb_k33``/``c_wk3`` are the keyframe rotations and board-centre positions; keyframe k
    is held over [hold_t0[k], hold_t1[k]] and the board moves to k+1 until hold_t0[k+1].
    ``kinds[k]`` says what the hold is for: 'shared', 'closeup:<cam>', 'floor' (the board at
    the world origin) or 'floor-extra' (flat on the floor elsewhere). A small
    smooth tremor (``tremor_m`` metres, about tremor_m / 0.3 m radians) rides on top, as
    with a hand-held board, except on the floor.
    """

    spec: BoardSpec
    R_wb_k33: np.ndarray
    c_wk3: np.ndarray
    hold_t0: np.ndarray
    hold_t1: np.ndarray
    kinds: list[str]
    tremor_m: float = 0.0
    seed: int = 0
    _tremor: tuple = field(default=(), repr=False)

    def __post_init__(self):
        rng = np.random.default_rng(self.seed + 7)
        # sum of sinusoids 0.5-3 Hz with random phases per axis (3 translation + 3 rotation)
        self._tremor = (rng.uniform(0.5, 3.0, (6, 4)), rng.uniform(0, 2 * np.pi, (6, 4)))
        self._rel = [Rotation.from_matrix(self.R_wb_k33[k].T @ self.R_wb_k33[k + 1]).as_rotvec()
                     for k in range(len(self.kinds) - 1)]

    @property
    def duration(self) -> float:
        return float(self.hold_t1[-1])

    def pose(self, t_n) -> tuple[np.ndarray, np.ndarray]:
        """Board-to-world (R (N, 3, 3), t (N, 3)) at reference times t (clamped to the session);
        t is the world position of the board origin (top-left pattern corner)."""
        t = np.clip(np.atleast_1d(np.asarray(t_n, float)), 0.0, self.duration)
        k = np.clip(np.searchsorted(self.hold_t0, t, side="right") - 1, 0, len(self.kinds) - 1)
        moving = (t > self.hold_t1[k]) & (k < len(self.kinds) - 1)
        kn = np.minimum(k + 1, len(self.kinds) - 1)
        span = np.maximum(self.hold_t0[kn] - self.hold_t1[k], 1e-9)
        s = np.where(moving, _min_jerk((t - self.hold_t1[k]) / span), 0.0)
        c = self.c_wk3[k] + s[:, None] * (self.c_wk3[kn] - self.c_wk3[k])
        rel = np.concatenate([np.reshape(self._rel, (-1, 3)), np.zeros((1, 3))])[k]
        R = self.R_wb_k33[k] @ Rotation.from_rotvec(rel * s[:, None]).as_matrix()
        if self.tremor_m > 0:
            fr, ph = self._tremor
            wave = np.sin(2 * np.pi * fr[None] * t[:, None, None] + ph[None]).sum(-1) / 2.0  # (N, 6)
            on_floor = np.char.startswith(np.array(self.kinds), "floor")[k] & ~moving
            wave[on_floor] = 0.0
            c = c + self.tremor_m * wave[:, :3]
            R = R @ Rotation.from_rotvec(self.tremor_m / 0.3 * wave[:, 3:]).as_matrix()
        t_wb = c - R @ self.spec.center_b3
        return R, t_wb

    def segments(self) -> list[dict]:
        out = []
        for k, kind in enumerate(self.kinds):
            out.append({"kind": kind, "t0": float(self.hold_t0[k]), "t1": float(self.hold_t1[k])})
        return out


def corner_visibility(cam: Camera, R_wb: np.ndarray, t_wb: np.ndarray, spec: BoardSpec,
                      max_angle_deg: float = 75.0, side: str = "front") -> float:
    """Fraction of chessboard corners a camera sees on the board's printed face (``side``
    "front"), on its back ("back": the side facing +z_b) or on whichever faces it ("any")."""
    R_cb = cam.R @ R_wb
    t_cb = cam.R @ t_wb + cam.t
    o_b = -R_cb.T @ t_cb  # camera centre in board coordinates
    c_b = spec.center_b3
    v = o_b - c_b
    # the front faces -z_b: a camera sees it from v[2] < 0, the back from v[2] > 0
    facing = {"front": -v[2], "back": v[2], "any": abs(v[2])}[side]
    if facing <= 0 or facing / np.linalg.norm(v) < np.cos(np.radians(max_angle_deg)):
        return 0.0
    X = spec.corners_b3 @ R_cb.T + t_cb
    if np.any(X[:, 2] < 0.05):
        return 0.0
    xy = cam.project(spec.corners_b3 @ R_wb.T + t_wb)
    w, h = cam.size
    m = 4.0
    inside = (xy[:, 0] > m) & (xy[:, 0] < w - 1 - m) & (xy[:, 1] > m) & (xy[:, 1] < h - 1 - m)
    return float(inside.mean())


def facing_rotation(normal_out: np.ndarray, up=np.array([0.0, 0.0, 1.0]), roll: float = 0.0) -> np.ndarray:
    """Board-to-world rotation whose printed face looks along ``normal_out`` (= -z_b), held
    upright (board y ~ world down), then rolled about the normal by ``roll`` radians."""
    z_b = -normal_out / np.linalg.norm(normal_out)
    y_b = -(up - (up @ z_b) * z_b)
    if np.linalg.norm(y_b) < 1e-6:
        y_b = np.array([0.0, 1.0, 0.0]) - z_b[1] * z_b
    y_b /= np.linalg.norm(y_b)
    x_b = np.cross(y_b, z_b)
    R = np.stack([x_b, y_b, z_b], 1)
    return R @ Rotation.from_rotvec([0, 0, roll]).as_matrix()


def _tilt(R_wb: np.ndarray, rng, max_deg: float) -> np.ndarray:
    """Tilt the board about a random in-plane axis by up to max_deg."""
    a = rng.uniform(0, 2 * np.pi)
    ang = np.radians(rng.uniform(0.3, 1.0) * max_deg)
    axis_b = np.array([np.cos(a), np.sin(a), 0.0])
    return R_wb @ Rotation.from_rotvec(axis_b * ang).as_matrix()


def volume_center(rig: Rig) -> np.ndarray:
    """Least-squares meeting point of the optical axes (the middle of the capture volume)."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c in rig:
        d = c.R[2]
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c.center
    try:
        p = np.linalg.solve(A + 1e-6 * np.eye(3), b)
    except np.linalg.LinAlgError:
        p = rig.centers().mean(0)
    return p


def plan_session(rig: Rig, spec: BoardSpec, *, seed: int = 0, duration_s: float = 60.0, closeups: bool = True,
                 n_closeups: int = 8, floor_pose: bool = True, hold_s: tuple[float, float] = (0.8, 1.6),
                 closeup_hold_s: tuple[float, float] = (0.3, 0.7), floor_hold_s: float = 2.5, floor_places: int = 3,
                 floor_radius: tuple[float, float] = (0.6, 1.2),
                 speed_mps: float = 0.8, tremor_m: float = 0.0003, volume_radius: float | None = None,
                 height_range: tuple[float, float] = (0.6, 1.8), closeup_fill: tuple[float, float] = (0.35, 0.8),
                 max_tilt_deg: float = 40.0, max_view_angle_deg: float = 55.0,
                 behind: Sequence[str] = ()) -> BoardTrajectory:
    """Plan a board session for a rig (world Z up). See the module docstring.

    ``behind`` names cameras that see the hand-held board only from behind, as a camera
    does that stands behind the person holding it: its shared holds face the pair's other
    camera with the back towards it, its close-ups show it the back, and no other hold
    shows it the front (the floor boards lie face up and are seen as they lie). Whether
    the back shows the pattern is the renderer's ``back``."""
    rng = np.random.default_rng(seed)
    cams = list(rig)
    behind = set(behind)
    unknown = behind - set(rig.names)
    if unknown:
        raise ValueError(f"behind: no camera {', '.join(sorted(unknown))} in the rig")

    def hides_front(R, t) -> bool:
        """No behind camera sees the board's front."""
        return all(corner_visibility(c, R, t, spec, max_angle_deg=89.0) == 0.0 for c in cams if c.name in behind)
    centre = volume_center(rig)
    dists = np.linalg.norm(rig.centers() - centre, axis=1)
    r_vol = volume_radius if volume_radius is not None else 0.3 * float(np.median(dists))
    lo, hi = height_range
    # cameras ordered by azimuth around the volume, so "neighbours" are adjacent on the ring
    az = np.arctan2(*(rig.centers() - centre)[:, [1, 0]].T)
    order = list(np.argsort(az))

    def shared_hold(k: int):
        """A hold facing the k-th pair of neighbouring cameras (by azimuth), seen well (not too
        obliquely) by both, or None."""
        i = order[k % len(order)]
        pair = [cams[i]] if len(cams) == 1 else [cams[i], cams[order[(k + 1) % len(order)]]]
        for _ in range(200):
            p = centre.copy()
            rr, aa = r_vol * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
            p[:2] += rr * np.array([np.cos(aa), np.sin(aa)])
            p[2] = rng.uniform(lo, hi)
            # the printed face turns towards the pair's front cameras and away from those behind
            dirs = [(-1.0 if c.name in behind else 1.0) * (c.center - p) / np.linalg.norm(c.center - p) for c in pair]
            n = np.mean(dirs, 0)
            R = _tilt(facing_rotation(n, roll=rng.uniform(-0.4, 0.4)), rng, 0.5 * max_tilt_deg)
            t = p - R @ spec.center_b3
            ok = [corner_visibility(c, R, t, spec, max_angle_deg=max_view_angle_deg,
                                    side="back" if c.name in behind else "front") > 0.8 for c in pair]
            if all(ok) and (not behind or hides_front(R, t)):
                return R, p
        return None

    def closeup_holds(cam: Camera, n: int):
        out = []
        w, h = cam.size
        f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
        diag_m = float(np.hypot(*spec.size_m))
        # image positions: centre, corners and edge midpoints (coverage), in random order
        grid = [(0.5, 0.5), (0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75), (0.5, 0.2), (0.5, 0.8),
                (0.2, 0.5), (0.8, 0.5)]
        rng.shuffle(grid)
        tries = 0
        while len(out) < n and tries < 60 * n:
            tries += 1
            gx, gy = grid[len(out) % len(grid)]
            jitter = rng.uniform(-0.08, 0.08, 2)
            fill = rng.uniform(*closeup_fill)
            depth = f * diag_m / (fill * np.hypot(w, h) * 0.9)
            uv = np.array([(gx + jitter[0]) * w, (gy + jitter[1]) * h])
            ray_c = np.r_[undistort_exact(cam, uv[None])[0], 1.0]
            p = cam.R.T @ (ray_c * depth - cam.t)
            n_out = (cam.center - p) / np.linalg.norm(cam.center - p)
            back = cam.name in behind
            R = _tilt(facing_rotation(-n_out if back else n_out, roll=rng.uniform(-0.6, 0.6)), rng,
                      max_tilt_deg * 1.1)
            t = p - R @ spec.center_b3
            if p[2] < 0.15 or corner_visibility(cam, R, t, spec, max_angle_deg=65,
                                                side="back" if back else "front") < 0.55:
                continue
            if behind and not hides_front(R, t):
                continue
            out.append((R, p))
        return out

    def move_time(p0, R0, p1, R1):
        ang = np.linalg.norm(Rotation.from_matrix(R0.T @ R1).as_rotvec())
        return max(0.5, np.linalg.norm(p1 - p0) / speed_mps * 1.3, ang / 1.5)

    def floor_holds(n: int):
        """Boards flat on the floor away from the origin, seen by at least two cameras: with
        the origin board they pin the floor plane over a wide baseline."""
        out = []
        c0 = np.array([centre[0], centre[1], 0.0])
        for _ in range(100 * n):
            if len(out) >= n:
                break
            a = rng.uniform(0, 2 * np.pi)
            rr = rng.uniform(*floor_radius) * r_vol
            R = R_WORLD_FLOOR_BOARD @ Rotation.from_rotvec([0, 0, rng.uniform(-np.pi, np.pi)]).as_matrix()
            p = c0 + rr * np.array([np.cos(a), np.sin(a), 0.0])
            t = p - R @ spec.center_b3
            if sum(corner_visibility(c, R, t, spec, max_angle_deg=80) > 0.8 for c in cams) >= min(2, len(cams)):
                out.append((R, p))
        return out

    close = {c.name: closeup_holds(c, n_closeups) if closeups else [] for c in cams}
    floor = (R_WORLD_FLOOR_BOARD, R_WORLD_FLOOR_BOARD @ spec.center_b3)  # board origin at the world origin
    extra_floor = floor_holds(floor_places - 1) if floor_pose else []
    # round-robin over neighbouring pairs, so that every pair gets its share
    pool = [h for h in (shared_hold(k) for k in range(max(8, int(duration_s)))) if h is not None]
    hold_len = rng.uniform(*hold_s, len(pool))
    close_len = {c.name: rng.uniform(*closeup_hold_s, len(close[c.name])) for c in cams}

    def sequence(n_shared: int):
        """The close-ups of one camera, then a batch of shared holds, ..., then the floor."""
        seq = []
        batches = np.array_split(np.arange(n_shared), max(1, len(cams)))
        for ci, c in enumerate(cams):
            seq += [(R, p, f"closeup:{c.name}", close_len[c.name][j]) for j, (R, p) in enumerate(close[c.name])]
            seq += [(pool[j][0], pool[j][1], "shared", hold_len[j]) for j in batches[ci]]
        if floor_pose:
            seq += [(R, p, "floor-extra", floor_hold_s) for R, p in extra_floor]
            seq.append((floor[0], floor[1], "floor", floor_hold_s))
        moves = [move_time(seq[k - 1][1], seq[k - 1][0], seq[k][1], seq[k][0]) for k in range(1, len(seq))]
        return seq, np.array(moves)

    # as many shared holds as fit the duration; when even two per neighbouring pair do not
    # fit, fewer close-ups (down to 3 per camera) before the moves get faster than a person
    n = len(pool)
    while True:
        poses, moves = sequence(n)
        total = 0.3 + sum(p[3] for p in poses) + moves.sum()
        if total <= duration_s:
            break
        if n > min(len(pool), 2 * len(cams)):
            n -= 1
        elif max(len(v) for v in close.values()) > 3:
            for c in cams:
                close[c.name] = close[c.name][:max(3, len(close[c.name]) - 1)]
        else:
            break
    if not poses:
        raise ValueError("board session has no poses")
    # stretch (or, for a too short duration, compress) the moves to fill the duration
    # exactly; if moving 2.5x faster than planned is not enough, holds get shorter too
    holds = np.array([p[3] for p in poses])
    spare = duration_s - 0.3 - holds.sum()
    if len(moves) and moves.sum() > 0:
        moves = moves * max(spare, 0.4 * moves.sum()) / moves.sum()
    over = 0.3 + holds.sum() + moves.sum() - duration_s
    if over > 1e-9:
        f = (duration_s - 0.3) / (holds.sum() + moves.sum())
        holds, moves = holds * f, moves * f
    t0s, t1s = [], []
    t = 0.3
    for k in range(len(poses)):
        if k:
            t += moves[k - 1]
        t0s.append(t)
        t += holds[k]
        t1s.append(t)
    t0s, t1s = np.array(t0s), np.array(t1s)
    return BoardTrajectory(spec, np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]),
                           t0s, t1s, [p[2] for p in poses], tremor_m=tremor_m, seed=seed)


# ---- rendering ----------------------------------------------------------------------------
class _Texture:
    """Board texture pyramid: 2-channel float32 (grey 0..255, coverage 1) over the paper,
    so that a lookup with a zero border gives premultiplied grey and anti-aliased paper edges."""

    def __init__(self, spec: BoardSpec, px_per_square: int = 256, margin_squares: float = 0.3,
                 see_through: bool = False):
        self.spec = spec
        p = int(px_per_square)
        # every level must halve exactly (an odd size would shift texels by up to half a
        # texel): a power-of-two square size and a margin of whole 32-texel blocks
        p = 1 << max(3, int(np.round(np.log2(p))))
        margin = max(32, int(round(margin_squares * p / 32)) * 32)
        grey = spec.image(p, margin_px=margin).astype(np.float32)
        if see_through:
            grey = see_through_print(grey, p)
        img = np.dstack([grey, np.ones_like(grey)])
        self.levels = []  # (image, px per metre, margin px)
        ppm = p / spec.square_m
        while True:
            self.levels.append((img, ppm, margin))
            if p <= 8:
                break
            if img.shape[0] % 2 or img.shape[1] % 2:
                break
            img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
            p //= 2
            ppm /= 2
            margin = margin / 2
        self.margin_m = margin / ppm

    def level_for(self, texel_m: float) -> tuple[np.ndarray, float, float]:
        """The coarsest level whose texels are no larger than ``texel_m``."""
        best = self.levels[0]
        for lv in self.levels:
            if 1.0 / lv[1] <= texel_m:
                best = lv
        return best


SEE_THROUGH_PAPER = 215.0  # the back of a thin sheet lit from the front: darker than its face
SEE_THROUGH_CONTRAST = 0.5  # the ink shows through at half its contrast ...
SEE_THROUGH_BLUR_SQUARES = 0.02  # ... scattered over about 2 % of a square


def see_through_print(grey: np.ndarray, px_per_square: int) -> np.ndarray:
    """The print of a thin sheet as seen through the paper from behind, in the front's own
    texel layout (the mirroring comes from looking at it from the other side): the ink
    blurred by the paper (a symmetric blur keeps the chessboard corners where they are) and
    at reduced contrast on a darker paper."""
    sigma = SEE_THROUGH_BLUR_SQUARES * px_per_square
    ink = 255.0 - cv2.GaussianBlur(grey, (0, 0), sigma)
    return (SEE_THROUGH_PAPER - SEE_THROUGH_CONTRAST * ink * SEE_THROUGH_PAPER / 255.0).astype(np.float32)


BACKS = ("plain", "mirror", "see-through")


def _background(cam: Camera, rng) -> np.ndarray:
    """A cluttered room-like RGB background (float32 0..255): smooth luminance texture with
    mild colour, plus hard-edged boxes and lines (candidates a marker detector must reject)."""
    w, h = cam.size
    lum = np.zeros((h, w), np.float32)
    for octave, amp in ((4, 45), (16, 22), (64, 10), (256, 5)):
        small = rng.standard_normal((max(2, h * octave // max(w, h)), max(2, octave))).astype(np.float32)
        lum += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    chroma = cv2.resize(rng.standard_normal((3, 4, 3)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    base = rng.uniform(90, 140)
    img = base + lum[..., None] + 12 * chroma
    for _ in range(25):
        x0, y0 = rng.integers(0, w), rng.integers(0, h)
        x1, y1 = x0 + rng.integers(5, max(6, w // 6)), y0 + rng.integers(5, max(6, h // 6))
        grey = rng.uniform(30, 220)
        col = tuple(float(grey * v) for v in rng.uniform(0.8, 1.2, 3))
        if rng.uniform() < 0.6:
            cv2.rectangle(img, (int(x0), int(y0)), (int(x1), int(y1)), col, -1)
        else:
            cv2.line(img, (int(x0), int(y0)), (int(x1), int(y1)), col, int(rng.integers(1, 4)))
    return np.clip(img, 0, 255).astype(np.float32)


class BoardRenderer:
    """Renders one camera's view of the board at given board poses (inverse mapping).

    ``back`` is what the board's back side shows: "plain" (grey card), "mirror" (printed on
    both sides, the back page the mirror image of the front glued exactly behind it, so
    every corner is seen at the same 3D point from either side) or "see-through" (a thin
    sheet printed on one side: the print shows through, blurred and at lower contrast).
    Seen from behind, the same board point carries the same pattern, so the image is the
    mirror image of the front by the geometry alone."""

    def __init__(self, cam: Camera, spec: BoardSpec, *, supersample: int = 3, seed: int = 0,
                 texture: _Texture | None = None, background: np.ndarray | None = None, back: str = "plain",
                 back_texture: _Texture | None = None):
        if back not in BACKS:
            raise ValueError(f"back must be one of {', '.join(BACKS)}, not {back!r}")
        self.cam = cam
        self.spec = spec
        self.s = int(supersample)
        self.tex = texture or _Texture(spec)
        self.back = back
        self.tex_back = {"plain": None, "mirror": self.tex,
                         "see-through": back_texture or (_Texture(spec, see_through=True) if back == "see-through"
                                                         else None)}[back]
        self.rays = ray_map(cam, pad=1)
        rng = np.random.default_rng(seed)
        self.background = _background(cam, rng)
        w, h = cam.size
        yy, xx = np.mgrid[0:h, 0:w]
        r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / (0.25 * (w * w + h * h))
        self.vignette = (1.0 - 0.25 * r2).astype(np.float32)[..., None]
        self.tint = rng.uniform(0.92, 1.05, 3).astype(np.float32)
        self.gain = float(rng.uniform(0.9, 1.1))
        self.background_lit = (self.background * self.vignette * self.gain).astype(np.float32)
        if background is not None:  # the scene itself (float32 0..255, as rendered, lens included)
            self.background = self.background_lit = np.asarray(background, np.float32)
        self._noise, self._noise_sigma, self._noise_k = None, None, 0
        # outline of the paper (board coords), densely sampled so distortion bends it right
        W, H = spec.size_m
        m = self.tex.margin_m
        u = np.linspace(-m, W + m, 40)
        v = np.linspace(-m, H + m, 40)
        self._outline_b = np.concatenate([np.stack([u, np.full_like(u, -m)], 1), np.stack([u, np.full_like(u, H + m)], 1),
                                          np.stack([np.full_like(v, -m), v], 1), np.stack([np.full_like(v, W + m), v], 1)])
        self._outline_b = np.c_[self._outline_b, np.zeros(len(self._outline_b))]

    def _bbox(self, R_cb, t_cb):
        cam = self.cam
        Xc = self._outline_b @ R_cb.T + t_cb
        w, h = cam.size
        if np.any(Xc[:, 2] <= 0.02):
            if np.all(Xc[:, 2] <= 0.02):
                return None
            return 0, 0, w, h
        Xw = (Xc - cam.t) @ cam.R
        xy = cam.project(Xw)
        if not np.all(np.isfinite(xy)):
            return 0, 0, w, h
        x0, y0 = np.floor(xy.min(0)).astype(int) - 2
        x1, y1 = np.ceil(xy.max(0)).astype(int) + 3
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
        if x1 <= x0 or y1 <= y0:
            return None
        return x0, y0, x1, y1

    def board_layer(self, R_cb: np.ndarray, t_cb: np.ndarray, bbox, s: int | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
        """(premultiplied grey, alpha) of the board over bbox, with s x s samples per pixel
        box-filtered. For a ray r (undistorted, z = 1) the board point is a homography of r:
        X_b = lam R^T r - R^T t with lam = (n . t) / (n . r), n = R[:, 2]."""
        x0, y0, x1, y1 = bbox
        s = self.s if s is None else int(s)
        h, w = (y1 - y0), (x1 - x0)
        # texture coordinates are a smooth function of the pixel position (lens field then a
        # homography): compute them per pixel on a 1-pixel padded grid and upsample
        # bilinearly to the sub-pixel samples (exact to first order; the 2nd-order term over
        # a third of a pixel is far below 0.001 px)
        c = self.rays[y0:y1 + 2, x0:x1 + 2]
        rx, ry = c[..., 0], c[..., 1]
        b = R_cb.T @ t_cb
        A = R_cb.T.tolist()  # python floats keep the arithmetic in float32
        dn = float(R_cb[:, 2] @ t_cb)
        o_b = -b  # camera centre in board coordinates
        tex = self.tex if o_b[2] < 0 else self.tex_back  # printed face towards the camera, else the back
        if tex is not None:
            f = 0.5 * (self.cam.K[0, 0] + self.cam.K[1, 1])
            # texture level from the sub-pixel sample footprint at the board plane's nearest point
            img, ppm, margin = tex.level_for(max(abs(dn), 1e-3) / (f * s))
        else:  # a plain back: grey card
            img, ppm, margin = self.tex.levels[-1]
            img = np.dstack([np.full(img.shape[:2], 150.0, np.float32), np.ones(img.shape[:2], np.float32)])
        den = A[2][0] * rx + A[2][1] * ry + A[2][2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = (np.float32(dn * ppm) / den).astype(np.float32, copy=False)
        inv[~(inv > 0)] = np.nan  # behind the camera: no board
        tx = (A[0][0] * rx + A[0][1] * ry + A[0][2]) * inv + float(margin - 0.5 - b[0] * ppm)
        ty = (A[1][0] * rx + A[1][1] * ry + A[1][2]) * inv + float(margin - 0.5 - b[1] * ppm)
        # keep maps finite and inside cv2.remap's fixed-point range
        for m in (tx, ty):
            np.nan_to_num(m, copy=False, nan=-1e4)
            np.clip(m, -1e4, 3e4, out=m)
        if s > 1:
            size = ((w + 2) * s, (h + 2) * s)
            tx = cv2.resize(tx, size, interpolation=cv2.INTER_LINEAR)[s:-s, s:-s]
            ty = cv2.resize(ty, size, interpolation=cv2.INTER_LINEAR)[s:-s, s:-s]
        else:
            tx, ty = tx[1:-1, 1:-1], ty[1:-1, 1:-1]
        ga = cv2.remap(img, tx, ty, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(0.0, 0.0))
        if s > 1:
            ga = cv2.resize(ga, (w, h), interpolation=cv2.INTER_AREA)
        return ga[..., 0], ga[..., 1]

    def render(self, poses_cb: Sequence[tuple[np.ndarray, np.ndarray]], rng, noise_sigma: float = 2.0,
               light_dir_c: np.ndarray | None = None) -> np.ndarray:
        """One RGB uint8 frame; several poses (the exposure's time samples) are averaged."""
        frame = self.background_lit.copy()
        n_used = len(poses_cb)
        # time samples already smooth the image: fewer spatial samples when there are several
        s = self.s if n_used == 1 else max(1, self.s - n_used + 1)
        layers = []
        for R_cb, t_cb in poses_cb:
            bb = self._bbox(R_cb, t_cb)
            if bb is not None:
                layers.append((bb, *self.board_layer(R_cb, t_cb, bb, s)))
        if layers:
            x0 = min(l[0][0] for l in layers)
            y0 = min(l[0][1] for l in layers)
            x1 = max(l[0][2] for l in layers)
            y1 = max(l[0][3] for l in layers)
            g = np.zeros((y1 - y0, x1 - x0), np.float32)
            a = np.zeros_like(g)
            for (bx0, by0, bx1, by1), gl, al in layers:
                g[by0 - y0:by1 - y0, bx0 - x0:bx1 - x0] += gl
                a[by0 - y0:by1 - y0, bx0 - x0:bx1 - x0] += al
            g /= n_used
            a /= n_used
            R_cb = poses_cb[n_used // 2][0]
            ld = np.array([0.3, -0.8, -0.5]) if light_dir_c is None else np.asarray(light_dir_c, float)
            ld = ld / np.linalg.norm(ld)
            shade = 0.65 + 0.35 * abs(float(R_cb[:, 2] @ ld))
            # paper white ~235, ink black ~20, under the shading, vignetting and gain
            lit = self.vignette[y0:y1, x0:x1] * (self.gain * shade)
            board = ((20.0 * a + g * (215.0 / 255.0)) * lit[..., 0])[..., None] * self.tint
            sub = frame[y0:y1, x0:x1]
            frame[y0:y1, x0:x1] = sub * (1 - a[..., None]) + board
        if noise_sigma > 0:
            # a bank of noise frames drawn once per camera (drawing 6 M normals per 1080p
            # frame took half the render time); consecutive frames never share one
            if self._noise is None or self._noise_sigma != noise_sigma:
                self._noise = np.empty((7,) + frame.shape, np.float32)
                for k in range(len(self._noise)):
                    cv2.randn(self._noise[k], 0.0, float(noise_sigma))
                self._noise_sigma = noise_sigma
            self._noise_k = (self._noise_k + 1 + int(rng.integers(len(self._noise) - 1))) % len(self._noise)
            frame += self._noise[self._noise_k]
        return cv2.convertScaleAbs(frame)

def _render_unit(unit) -> dict:
    """One process's share of a board session: some cameras, the session's plan given."""
    out_dir, rig, spec, kw = unit
    return render_board_session(out_dir, rig, spec, **kw)


def _rig_board_poses(cam: Camera, R_wb: np.ndarray, t_wb: np.ndarray):
    """Board-to-camera poses for arrays of board-to-world poses."""
    R_cb = cam.R[None] @ R_wb
    t_cb = t_wb @ cam.R.T + cam.t
    return R_cb, t_cb


def render_board_session(out_dir: str | Path, rig: Rig, spec: BoardSpec, *, seed: int = 0, duration_s: float = 60.0,
                         fps: float = 30.0, clocks: Mapping[str, ClockModel] | None = None,
                         frame_times: Mapping[str, np.ndarray] | None = None, floor_pose: bool = True,
                         closeups: bool = True, n_closeups: int = 8, noise_sigma: float = 2.0,
                         exposure_s: float = 1 / 120, motion_blur: bool = True, supersample: int = 3,
                         tremor_m: float = 0.0003, crf: int = 18, writer_options: Mapping[str, dict] | None = None,
                         video_ext: str = ".mp4", trajectory: BoardTrajectory | None = None,
                         cameras: Sequence[str] | None = None, progress: bool = True,
                         backgrounds: Mapping[str, np.ndarray] | None = None, back: str = "plain",
                         behind: Sequence[str] = (), workers: int | None = 1, **plan_kw) -> dict:
    """Render a board session as one video per camera: ``out_dir/<cam><video_ext>``.

    Parameters (what a recipe's [board] table maps onto):
      rig          cameras with true intrinsics, lens model and world-to-camera pose (world Z up)
      spec         the board as printed (a spec differing from the one given to calibrate
                   reproduces a wrong-dictionary / legacy / inverted print)
      seed         everything random (trajectory, background, noise)
      duration_s   session length in reference (scene) time; the plan is stretched to it
      fps          nominal frame rate, used when ``frame_times`` is not given
      clocks       per camera true clock (t_ref = (1 + rate) t_cam + offset); identity if absent.
                   The videos carry camera-clock timestamps; the board is rendered at t_ref.
      frame_times  per camera camera-clock frame timestamps (e.g. VFR with jitter); default
                   k / fps for k in range(round(duration_s * fps))
      floor_pose   end with the board flat on the floor (pins the world frame): first at
                   ``floor_places - 1`` places around the middle (plan_kw floor_places, default 3),
                   last with its origin at the world origin, axes on the world's
      closeups     per camera ``n_closeups`` close, tilted holds covering the image (intrinsics)
      noise_sigma  sensor noise (8-bit levels); crf is the H.264 quality
      exposure_s, motion_blur   exposure time; with motion_blur the board is averaged over it
      supersample  sub-pixel samples per axis (anti-aliasing)
      tremor_m     hand tremor amplitude (m) on hand-held holds
      writer_options  per camera VideoWriter keywords (codec, bit_depth, hlg, orientation: the
                   file as the phone writes it; Recipe.writer_options); default H.264 8-bit
      trajectory   a ready BoardTrajectory instead of planning one
      cameras      render only these cameras (the trajectory still sees the whole rig)
      backgrounds  per camera the empty scene behind the board (float32 RGB 0..255, e.g.
                   CameraRenderer.static_image()); default: a random cluttered backdrop
      back         what the board's back shows: "plain" grey card, "mirror" (printed on both
                   sides, the back page the front's mirror image) or "see-through" (thin paper:
                   the front's print through it); see :class:`BoardRenderer`
      behind       cameras that see the hand-held board only from behind (planned so by
                   :func:`plan_session`; ignored with a ready ``trajectory``)
      workers      render the cameras in this many processes (None: one per CPU); the videos
                   are the same as rendered in one
      plan_kw      passed to :func:`plan_session` (hold_s, volume_radius, height_range, ...)

    Returns a dict: ``videos`` {cam: path}, ``frame_times`` {cam: camera-clock times},
    ``ref_times`` {cam: reference times}, ``visible`` {cam: fraction of corners in view per
    frame, on the front or on a printed back}, ``from_behind`` {cam: (F,) bool, the camera
    faces the board's back}, ``pose_times`` (N,), ``R_wb`` (N, 3, 3), ``t_wb`` (N, 3) board-to-world at
    100 Hz, ``segments`` [{kind, t0, t1}] (holds in reference time), ``floor`` (the floor
    board pose or None), ``trajectory`` (the BoardTrajectory) and ``spec``.
    """
    from mamma_kit.video.writer import VideoWriter

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if behind:
        plan_kw["behind"] = behind
    traj = trajectory or plan_session(rig, spec, seed=seed, duration_s=duration_s, closeups=closeups,
                                      n_closeups=n_closeups, floor_pose=floor_pose, tremor_m=tremor_m, **plan_kw)
    clocks = dict(clocks or {})
    result: dict = {"videos": {}, "frame_times": {}, "ref_times": {}, "visible": {}, "from_behind": {}}
    names = list(cameras) if cameras is not None else rig.names
    from mamma_kit.core.executor import default_workers, run_units

    if default_workers(len(names), workers) > 1:
        kw = dict(seed=seed, duration_s=duration_s, fps=fps, clocks=clocks, noise_sigma=noise_sigma,
                  exposure_s=exposure_s, motion_blur=motion_blur, supersample=supersample, crf=crf,
                  writer_options=writer_options, video_ext=video_ext, trajectory=traj, progress=progress, back=back,
                  workers=1)
        units = [(out_dir, rig, spec, kw | {"cameras": [n],
                                            "frame_times": {n: frame_times[n]} if frame_times and n in frame_times
                                            else None,
                                            "backgrounds": {n: backgrounds[n]} if backgrounds and n in backgrounds
                                            else None})
                 for n in names]
        for part in run_units(_render_unit, units, workers):
            for key in result:
                result[key].update(part[key])
        names = []
    tex = _Texture(spec)
    tex_back = _Texture(spec, see_through=True) if back == "see-through" else None
    for name in names:
        ci = rig.names.index(name)  # seeds depend on the camera, not on which others are rendered
        rng = np.random.default_rng([seed + 1000, ci])
        cam = rig[name]
        clk = clocks.get(name, ClockModel())
        if frame_times is not None and name in frame_times:
            t_cam = np.asarray(frame_times[name], float)
        else:
            t_cam = np.arange(int(round(duration_s * fps))) / fps
        t_ref = clk.to_ref(t_cam)
        ren = BoardRenderer(cam, spec, supersample=supersample, seed=seed * 101 + ci, texture=tex,
                            background=(backgrounds or {}).get(name), back=back, back_texture=tex_back)
        cv2.setRNGSeed(seed * 101 + ci)  # the sensor noise (cv2.randn) is reproducible too
        R_wb, t_wb = traj.pose(t_ref)
        side = "front" if back == "plain" else "any"
        vis = np.array([corner_visibility(cam, R_wb[i], t_wb[i], spec, 89.0, side) for i in range(len(t_ref))])
        # the camera centre on the board's +z side: it faces the back
        o_b = np.einsum("nji,nj->ni", R_wb, cam.center[None] - t_wb)
        result["from_behind"][name] = o_b[:, 2] > 0
        path = out_dir / f"{name}{video_ext}"
        nominal = 1.0 / np.median(np.diff(t_cam)) if len(t_cam) > 1 else fps
        with VideoWriter(path, cam.width, cam.height, fps=nominal, crf=crf,
                         **(writer_options or {}).get(name, {})) as wr:
            items = range(len(t_cam))
            for i in (track(items, f"board video {name}") if progress else items):
                times = [t_ref[i]]
                if motion_blur and exposure_s > 0:
                    # enough time samples that the board moves < 0.5 px between them
                    tt = t_ref[i] + np.array([-0.5, 0.5]) * exposure_s * (1 + clk.rate)
                    Rs, ts = traj.pose(tt)
                    c0 = cam.project(spec.corners_b3 @ Rs[0].T + ts[0])
                    c1 = cam.project(spec.corners_b3 @ Rs[1].T + ts[1])
                    d = np.nanmax(np.linalg.norm(c1 - c0, axis=1)) if np.any(np.isfinite(c0 - c1)) else 0.0
                    n_sub = int(np.clip(np.ceil(d / 0.75), 1, 6))
                    if n_sub > 1:
                        times = t_ref[i] + (np.arange(n_sub) + 0.5 - n_sub / 2) / n_sub * exposure_s * (1 + clk.rate)
                Rs, ts = traj.pose(np.asarray(times))
                R_cb, t_cb = _rig_board_poses(cam, Rs, ts)
                frame = ren.render(list(zip(R_cb, t_cb)), rng, noise_sigma=noise_sigma)
                wr.write_frame(frame, float(t_cam[i]))
        result["videos"][name] = str(path)
        result["frame_times"][name] = t_cam
        result["ref_times"][name] = t_ref
        result["visible"][name] = vis
    pt = np.arange(0.0, traj.duration + 1e-9, 0.01)
    R_all, t_all = traj.pose(pt)
    floor = None
    if "floor" in traj.kinds:
        k = traj.kinds.index("floor")
        Rf, tf = traj.pose([0.5 * (traj.hold_t0[k] + traj.hold_t1[k])])
        floor = {"t0": float(traj.hold_t0[k]), "t1": float(traj.hold_t1[k]), "R_wb": Rf[0], "t_wb": tf[0]}
    result.update(pose_times=pt, R_wb=R_all, t_wb=t_all, segments=traj.segments(), floor=floor,
                  trajectory=traj, spec=spec.to_dict())
    return result
