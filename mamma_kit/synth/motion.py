"""A procedural motion library in SMPL-X parameter space.

Poses are built per joint from Euler angles (radians, XYZ, in the joint's rest frame:
SMPL-X canonical axes, Y up, facing +Z, the body's left is +X) and clamped to joint
limits; every angle is a smooth function of time (sums of sinusoids and smoothsteps), so
motions are smooth and can be sampled at any scene time. The root is placed in mamma-kit's
Z-up world by a fixed rotation (canonical +Y -> world +Z) and a heading about world Z.

Sign conventions used below (rest frame of each joint):
    hip flexion (thigh forward)  -X      knee flexion  +X      spine forward bend  +X
    ankle dorsiflexion (toes up) -X
    left hip abduction           +Z      right hip abduction   -Z
    left shoulder: raise arm     +Z      arm forward           -Y    (right: mirrored)
    left elbow flexion           -Y      right elbow flexion   +Y
    left finger curl             -Z      right finger curl     +Z
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

N_JOINTS = 55
PELVIS, L_HIP, R_HIP, SPINE1, L_KNEE, R_KNEE, SPINE2, L_ANKLE, R_ANKLE, SPINE3 = range(10)
L_FOOT, R_FOOT, NECK, L_COLLAR, R_COLLAR, HEAD, L_SHOULDER, R_SHOULDER, L_ELBOW, R_ELBOW = range(10, 20)
L_WRIST, R_WRIST, JAW, L_EYE, R_EYE = range(20, 25)
L_HAND = list(range(25, 40))  # index1-3, middle1-3, pinky1-3, ring1-3, thumb1-3
R_HAND = list(range(40, 55))

# joint limits (radians) per Euler component, (lo, hi) for x, y, z; unlisted joints: +-0.6
_D = np.radians
LIMITS = {
    L_HIP: ((-2.2, 0.6), (-0.8, 0.8), (-0.5, 1.2)), R_HIP: ((-2.2, 0.6), (-0.8, 0.8), (-1.2, 0.5)),
    L_KNEE: ((0.0, 2.4), (-0.2, 0.2), (-0.1, 0.1)), R_KNEE: ((0.0, 2.4), (-0.2, 0.2), (-0.1, 0.1)),
    L_ANKLE: ((-0.7, 0.9), (-0.4, 0.4), (-0.4, 0.4)), R_ANKLE: ((-0.7, 0.9), (-0.4, 0.4), (-0.4, 0.4)),
    SPINE1: ((-0.5, 0.9), (-0.6, 0.6), (-0.4, 0.4)), SPINE2: ((-0.4, 0.6), (-0.5, 0.5), (-0.4, 0.4)),
    SPINE3: ((-0.4, 0.6), (-0.5, 0.5), (-0.4, 0.4)), NECK: ((-0.6, 0.8), (-0.9, 0.9), (-0.5, 0.5)),
    HEAD: ((-0.5, 0.6), (-0.6, 0.6), (-0.4, 0.4)),
    L_COLLAR: ((-0.3, 0.3), (-0.4, 0.4), (-0.3, 0.5)), R_COLLAR: ((-0.3, 0.3), (-0.4, 0.4), (-0.5, 0.3)),
    L_SHOULDER: ((-1.5, 1.5), (-1.7, 1.2), (-1.5, 1.6)), R_SHOULDER: ((-1.5, 1.5), (-1.2, 1.7), (-1.6, 1.5)),
    L_ELBOW: ((-0.3, 0.3), (-2.5, 0.05), (-0.2, 0.2)), R_ELBOW: ((-0.3, 0.3), (-0.05, 2.5), (-0.2, 0.2)),
    L_WRIST: ((-0.9, 0.9), (-0.5, 0.5), (-0.9, 0.9)), R_WRIST: ((-0.9, 0.9), (-0.5, 0.5), (-0.9, 0.9)),
    L_FOOT: ((-0.5, 0.5), (-0.2, 0.2), (-0.2, 0.2)), R_FOOT: ((-0.5, 0.5), (-0.2, 0.2), (-0.2, 0.2)),
}
for _j in L_HAND[:12]:
    LIMITS[_j] = ((-0.2, 0.2), (-0.3, 0.3), (-1.7, 0.2))
for _j in R_HAND[:12]:
    LIMITS[_j] = ((-0.2, 0.2), (-0.3, 0.3), (-0.2, 1.7))
for _j in L_HAND[12:] + R_HAND[12:]:
    LIMITS[_j] = ((-0.8, 0.8), (-0.8, 0.8), (-0.8, 0.8))

# canonical (Y up, facing +Z) -> world (Z up, facing -Y at heading 0)
R_CANON_TO_WORLD = Rotation.from_euler("x", 90, degrees=True)
FINGER_NAMES = ("index", "middle", "pinky", "ring", "thumb")


def heading_of(direction_xy: np.ndarray) -> np.ndarray:
    """Heading angle (about world Z) that makes a body face ``direction_xy`` (..., 2)."""
    d = np.asarray(direction_xy, float)
    return np.arctan2(d[..., 0], -d[..., 1])


def facing(heading: np.ndarray) -> np.ndarray:
    """Unit facing direction (..., 2) of a heading."""
    return np.stack([np.sin(heading), -np.cos(heading)], -1)


def smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


@dataclass
class PersonTrack:
    """Time functions of one person, sampled at ``times`` (N,)."""

    euler: np.ndarray  # (N, 55, 3) local joint angles
    xy: np.ndarray  # (N, 2) world position of the pelvis
    heading: np.ndarray  # (N,) radians about world Z
    lift: np.ndarray  # (N,) extra pelvis height (jumps), m
    root_euler: np.ndarray  # (N, 3) root tilt in the canonical frame (lying, leaning)
    ground: str = "feet"  # what touches the floor: feet | lowest


@dataclass
class MotionClip:
    """SMPL-X parameters of P people sampled densely over scene time.

    params[key]: (P, N, D) for global_orient 3, body_pose 63, left/right_hand_pose 45,
    jaw_pose/leye_pose/reye_pose 3, expression 10, transl 3. betas: (P, 16).
    """

    times: np.ndarray
    betas: np.ndarray
    params: dict[str, np.ndarray]
    kind: str = ""
    contacts: list[dict] = field(default_factory=list)  # interaction targets (for refinement)

    @property
    def n_people(self) -> int:
        return self.betas.shape[0]

    def at(self, s) -> dict[str, np.ndarray]:
        """Parameters at scene time(s) s (scalar or (M,)) -> each (P, M, D) (or (P, D))."""
        s_arr = np.atleast_1d(np.asarray(s, float))
        s_cl = np.clip(s_arr, self.times[0], self.times[-1])
        out = {}
        for k, v in self.params.items():
            if k == "global_orient":
                per = []
                for p in range(self.n_people):
                    sl = Slerp(self.times, Rotation.from_rotvec(v[p]))
                    per.append(sl(s_cl).as_rotvec())
                out[k] = np.stack(per)
            else:
                idx = np.clip(np.searchsorted(self.times, s_cl) - 1, 0, len(self.times) - 2)
                t0, t1 = self.times[idx], self.times[idx + 1]
                w = ((s_cl - t0) / np.maximum(t1 - t0, 1e-12))[None, :, None]
                out[k] = v[:, idx] * (1 - w) + v[:, idx + 1] * w
        if np.ndim(s) == 0:
            out = {k: v[:, 0] for k, v in out.items()}
        return out


def _clamp(euler: np.ndarray) -> np.ndarray:
    out = euler.copy()
    lo = np.full((N_JOINTS, 3), -0.6)
    hi = np.full((N_JOINTS, 3), 0.6)
    lo[0], hi[0] = -np.pi, np.pi
    for j, lim in LIMITS.items():
        lo[j] = [a for a, _ in lim]
        hi[j] = [b for _, b in lim]
    return np.clip(out, lo, hi)


_ARM_CHAIN = {"left": (L_SHOULDER, [L_ELBOW, L_WRIST] + L_HAND), "right": (R_SHOULDER, [R_ELBOW, R_WRIST] + R_HAND)}


def euler_to_params(track: PersonTrack, arm_rest: dict[str, Rotation] | None = None) -> dict[str, np.ndarray]:
    """Per-joint Euler angles + root placement -> SMPL-X parameter arrays (N, D), transl
    holding the pelvis xy (the floor height is fixed later, with the body model).

    ``arm_rest`` (from ``body.rest_pose.arm_rest_rotations``) re-expresses T-pose-relative arm angles
    for a model with another rest pose: shoulder R Q, every joint below it Q^-1 R Q."""
    e = _clamp(track.euler)
    N = e.shape[0]
    rots = Rotation.from_euler("xyz", e.reshape(-1, 3))
    aa = rots.as_rotvec().reshape(N, N_JOINTS, 3)
    if arm_rest:
        for side, (sh, below) in _ARM_CHAIN.items():
            Q = arm_rest[side]
            aa[:, sh] = (Rotation.from_rotvec(aa[:, sh]) * Q).as_rotvec()
            for j in below:
                aa[:, j] = (Q.inv() * Rotation.from_rotvec(aa[:, j]) * Q).as_rotvec()
    root_local = Rotation.from_euler("xyz", track.root_euler)
    glob = Rotation.from_euler("z", np.asarray(track.heading)[:, None]) * R_CANON_TO_WORLD * root_local
    transl = np.c_[track.xy, track.lift]
    return {
        "global_orient": glob.as_rotvec().reshape(N, 3),
        "body_pose": aa[:, 1:22].reshape(N, 63),
        "left_hand_pose": aa[:, 25:40].reshape(N, 45),
        "right_hand_pose": aa[:, 40:55].reshape(N, 45),
        "jaw_pose": aa[:, JAW], "leye_pose": aa[:, L_EYE], "reye_pose": aa[:, R_EYE],
        "expression": np.zeros((N, 10)),
        "transl": transl,
    }


# ---- building blocks --------------------------------------------------------------------
class _Gen:
    """Random smooth signals for one person."""

    def __init__(self, rng: np.random.Generator, t: np.ndarray):
        self.rng, self.t = rng, t

    def wiggle(self, amp: float, freq=(0.2, 0.8), n: int = 3) -> np.ndarray:
        """A smooth random signal: sum of n sinusoids, amplitude ~amp."""
        out = np.zeros_like(self.t)
        for _ in range(n):
            f = self.rng.uniform(*freq)
            out += np.sin(2 * np.pi * f * self.t + self.rng.uniform(0, 2 * np.pi)) / n
        return amp * out


def rest_pose(N: int) -> np.ndarray:
    """Relaxed standing: arms down at the sides, slight elbow and finger flexion."""
    e = np.zeros((N, N_JOINTS, 3))
    e[:, L_SHOULDER, 2] = -1.2
    e[:, R_SHOULDER, 2] = 1.2
    e[:, L_ELBOW, 1] = -0.25
    e[:, R_ELBOW, 1] = 0.25
    for j in L_HAND[:12]:
        e[:, j, 2] = -0.25
    for j in R_HAND[:12]:
        e[:, j, 2] = 0.25
    return e


def add_idle(e: np.ndarray, g: _Gen, amount: float = 1.0) -> None:
    """Breathing, sway and small head/arm motion, so nobody is ever perfectly still."""
    e[:, SPINE1, 0] += amount * g.wiggle(0.04)
    e[:, SPINE2, 2] += amount * g.wiggle(0.03)
    e[:, NECK, 1] += amount * g.wiggle(0.25, (0.1, 0.4))
    e[:, HEAD, 0] += amount * g.wiggle(0.1)
    e[:, L_SHOULDER, 2] += amount * g.wiggle(0.1)
    e[:, R_SHOULDER, 2] += amount * g.wiggle(0.1)
    e[:, L_ELBOW, 1] += amount * (g.wiggle(0.15) - 0.1)
    e[:, R_ELBOW, 1] += amount * (g.wiggle(0.15) + 0.1)


def set_fingers(e: np.ndarray, side: str, curl: np.ndarray, spread: np.ndarray | float = 0.0,
                thumb: np.ndarray | float = 0.3, per_finger: np.ndarray | None = None) -> None:
    """Curl (0 open .. 1 fist) each finger of one hand; ``per_finger`` (N, 4) overrides."""
    joints = L_HAND if side == "left" else R_HAND
    sign = -1.0 if side == "left" else 1.0
    curl = np.broadcast_to(np.asarray(curl, float), e.shape[:1])
    for f in range(4):
        c = per_finger[:, f] if per_finger is not None else curl
        for k in range(3):
            j = joints[3 * f + k]
            e[:, j, 2] = sign * c * (1.3 if k else 1.1)
            if k == 0:
                e[:, j, 1] = sign * (np.asarray(spread) * (f - 1.5) * 0.12)
    th = np.broadcast_to(np.asarray(thumb, float), e.shape[:1])
    for k in range(3):
        j = joints[12 + k]
        e[:, j, 0] = 0.4 * th
        e[:, j, 2] = sign * 0.6 * th


def gait(e: np.ndarray, phase: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """Walking cycle driven by ``phase`` (radians) with amplitude by ``speed`` (0..1.5 m/s).
    Returns the pelvis bob (m)."""
    a = np.clip(speed / 1.2, 0, 1.3)
    s = np.sin(phase)
    e[:, L_HIP, 0] += -0.45 * a * s
    e[:, R_HIP, 0] += 0.45 * a * s
    # knee flexes during swing: when the hip moves forward
    e[:, L_KNEE, 0] += a * (0.15 + 0.55 * np.clip(np.sin(phase + 0.9), 0, None))
    e[:, R_KNEE, 0] += a * (0.15 + 0.55 * np.clip(np.sin(phase + 0.9 + np.pi), 0, None))
    e[:, L_ANKLE, 0] += 0.2 * a * np.sin(phase + 1.6)
    e[:, R_ANKLE, 0] += 0.2 * a * np.sin(phase + 1.6 + np.pi)
    # arms swing opposite to legs
    e[:, L_SHOULDER, 1] += 0.35 * a * s
    e[:, R_SHOULDER, 1] += 0.35 * a * s
    e[:, SPINE2, 1] += 0.08 * a * s
    return 0.025 * a * np.cos(2 * phase)


def squat_pose(e: np.ndarray, depth: np.ndarray) -> None:
    """Squat by ``depth`` in 0..1 (1 = thighs about horizontal), arms forward for balance."""
    e[:, L_HIP, 0] += -1.5 * depth
    e[:, R_HIP, 0] += -1.5 * depth
    e[:, L_HIP, 2] += 0.2 * depth
    e[:, R_HIP, 2] += -0.2 * depth
    e[:, L_KNEE, 0] += 2.0 * depth
    e[:, R_KNEE, 0] += 2.0 * depth
    # the shin tilts forward by (knee - hip flexion): dorsiflex the ankle as much so the
    # foot stays flat (dorsiflexion is -X: +X points the toes down)
    e[:, L_ANKLE, 0] += -0.5 * depth
    e[:, R_ANKLE, 0] += -0.5 * depth
    e[:, SPINE1, 0] += 0.45 * depth
    e[:, L_SHOULDER, 2] += 1.1 * depth
    e[:, R_SHOULDER, 2] += -1.1 * depth
    e[:, L_SHOULDER, 1] += -1.2 * depth
    e[:, R_SHOULDER, 1] += 1.2 * depth


def _path(g: _Gen, t: np.ndarray, area: float, centre: np.ndarray, speed: float) -> tuple[np.ndarray, np.ndarray]:
    """A smooth closed walking path (ellipse with wobble) inside the area; returns xy, speed."""
    rx, ry = area * g.rng.uniform(0.25, 0.4), area * g.rng.uniform(0.2, 0.35)
    perim = 2 * np.pi * np.sqrt((rx * rx + ry * ry) / 2)
    w = 2 * np.pi * speed / perim * g.rng.choice([-1, 1])
    ph0 = g.rng.uniform(0, 2 * np.pi)
    ang = ph0 + w * t + 0.2 * np.sin(0.5 * w * t)
    xy = centre + np.stack([rx * np.cos(ang), ry * np.sin(ang)], -1)
    return xy


def _heading_along(xy: np.ndarray, t: np.ndarray, fallback: float) -> tuple[np.ndarray, np.ndarray]:
    v = np.gradient(xy, t, axis=0)
    spd = np.linalg.norm(v, axis=1)
    h = np.where(spd > 0.05, heading_of(v), fallback)
    return np.unwrap(h), spd


# ---- single-person motions --------------------------------------------------------------
def single_motion(kind: str, t: np.ndarray, rng: np.random.Generator, centre: np.ndarray, area: float,
                  face_heading: float) -> PersonTrack:
    """One person's motion of a given kind around ``centre``."""
    N = len(t)
    g = _Gen(rng, t)
    e = rest_pose(N)
    add_idle(e, g)
    xy = np.repeat(centre[None], N, 0).astype(float)
    heading = np.full(N, face_heading) + g.wiggle(0.15, (0.05, 0.2))
    lift = np.zeros(N)
    root = np.zeros((N, 3))
    ground = "feet"
    curl = 0.3 + g.wiggle(0.2, (0.2, 0.6))
    set_fingers(e, "left", curl)
    set_fingers(e, "right", 0.3 + g.wiggle(0.2, (0.2, 0.6)))
    if kind in ("walk", "crowd"):
        speed = rng.uniform(0.8, 1.3)
        xy = _path(g, t, area, centre, speed)
        heading, spd = _heading_along(xy, t, face_heading)
        stride = 1.4
        phase = 2 * np.pi * np.cumsum(np.r_[0, np.diff(t)] * spd / stride) + rng.uniform(0, 2 * np.pi)
        lift = gait(e, phase, spd)
        # pelvis height drops slightly with knee flexion in the gait (handled by ground placement)
    elif kind == "turn":
        w = rng.choice([-1, 1]) * rng.uniform(0.8, 1.6)
        heading = face_heading + w * t
        phase = 2 * np.pi * 1.2 * t
        gait(e, phase, np.full(N, 0.35))
    elif kind == "squat":
        period = rng.uniform(2.0, 3.0)
        depth = 0.5 - 0.5 * np.cos(2 * np.pi * t / period)
        squat_pose(e, depth * rng.uniform(0.7, 1.0))
    elif kind == "jump":
        period = rng.uniform(1.4, 1.8)
        ph = (t / period) % 1.0
        crouch = np.exp(-((ph - 0.3) / 0.1) ** 2) + 0.7 * np.exp(-((ph - 0.75) / 0.08) ** 2)
        squat_pose(e, 0.45 * crouch)
        air = np.clip(np.sin(np.pi * (ph - 0.42) / 0.28), 0, None) * ((ph > 0.42) & (ph < 0.70))
        lift = 0.35 * air
        # arms swing up during take-off
        e[:, L_SHOULDER, 2] += 1.6 * air
        e[:, R_SHOULDER, 2] -= 1.6 * air
        e[:, L_ANKLE, 0] += 0.5 * air  # toes point down in the air
        e[:, R_ANKLE, 0] += 0.5 * air
    elif kind in ("gestures", "stand"):
        amt = 1.0 if kind == "gestures" else 0.2
        # wave, point and reach with alternating arms; fingers count and make fists
        e[:, L_SHOULDER, 2] += amt * (1.0 + g.wiggle(1.0, (0.2, 0.5)))
        e[:, R_SHOULDER, 2] -= amt * (1.0 + g.wiggle(1.0, (0.2, 0.5)))
        e[:, L_SHOULDER, 1] += amt * g.wiggle(0.9, (0.15, 0.4))
        e[:, R_SHOULDER, 1] += amt * g.wiggle(0.9, (0.15, 0.4))
        e[:, L_ELBOW, 1] += amt * (-0.8 + g.wiggle(0.7, (0.3, 0.9)))
        e[:, R_ELBOW, 1] += amt * (0.8 + g.wiggle(0.7, (0.3, 0.9)))
        e[:, L_WRIST, 2] += amt * g.wiggle(0.6, (0.5, 1.2))
        e[:, R_WRIST, 0] += amt * g.wiggle(0.6, (0.5, 1.2))
        if kind == "gestures":
            per = np.clip(0.5 + np.stack([g.wiggle(0.8, (0.3, 0.8)) for _ in range(4)], 1), 0, 1)
            set_fingers(e, "left", 0, spread=g.wiggle(1.0), per_finger=per, thumb=0.5 + g.wiggle(0.5))
            per = np.clip(0.5 + np.stack([g.wiggle(0.8, (0.3, 0.8)) for _ in range(4)], 1), 0, 1)
            set_fingers(e, "right", 0, spread=g.wiggle(1.0), per_finger=per, thumb=0.5 + g.wiggle(0.5))
        e[:, SPINE1, 1] += amt * g.wiggle(0.3, (0.1, 0.3))
    elif kind == "floor":
        ground = "lowest"
        style = rng.choice(["sit", "lie", "yoga"])
        if style == "sit":  # sitting on the floor, legs forward, leaning on the arms
            e[:, L_HIP, 0] += -1.5
            e[:, R_HIP, 0] += -1.5
            e[:, L_KNEE, 0] += 0.4 + g.wiggle(0.3)
            e[:, R_KNEE, 0] += 0.6 + g.wiggle(0.3)
            e[:, SPINE1, 0] += -0.1
            e[:, L_SHOULDER, 1] += 0.5
            e[:, R_SHOULDER, 1] += -0.5
            e[:, L_SHOULDER, 2] += -0.1
            e[:, R_SHOULDER, 2] += 0.1
        elif style == "lie":  # lying on the back, knees and arms moving
            root[:, 0] = -np.pi / 2
            e[:, L_KNEE, 0] += 0.6 + g.wiggle(0.5)
            e[:, R_KNEE, 0] += 0.3 + g.wiggle(0.5)
            e[:, L_HIP, 0] += -0.4 + g.wiggle(0.3)
            e[:, R_HIP, 0] += -0.2 + g.wiggle(0.3)
            e[:, L_SHOULDER, 2] += 0.9 + g.wiggle(0.6)
            e[:, R_SHOULDER, 2] += -0.9 + g.wiggle(0.6)
        else:  # warrior-like lunge with arms out
            e[:, L_HIP, 0] += -1.0
            e[:, L_KNEE, 0] += 1.1
            e[:, R_HIP, 0] += 0.35
            e[:, R_HIP, 2] += -0.3
            e[:, L_HIP, 2] += 0.2
            e[:, L_SHOULDER, 2] += 1.15 + g.wiggle(0.15)
            e[:, R_SHOULDER, 2] += -1.15 + g.wiggle(0.15)
            e[:, L_ELBOW, 1] = 0.0
            e[:, R_ELBOW, 1] = 0.0
            set_fingers(e, "left", 0.05)
            set_fingers(e, "right", 0.05)
    elif kind == "mixed":
        # blend walk -> squat -> gestures over the clip
        seg = len(t) // 3 or 1
        parts = [single_motion(k, t, rng, centre, area, face_heading) for k in ("walk", "squat", "gestures")]
        w = np.zeros((N, 3))
        x = t / max(t[-1] - t[0], 1e-6) if N > 1 else np.zeros(N)
        w[:, 0] = 1 - smoothstep((x - 0.28) / 0.1)
        w[:, 2] = smoothstep((x - 0.62) / 0.1)
        w[:, 1] = 1 - w[:, 0] - w[:, 2]
        e = sum(w[:, i, None, None] * parts[i].euler for i in range(3))
        xy = parts[0].xy * w[:, :1] + parts[0].xy[seg][None] * (1 - w[:, :1])
        heading = parts[0].heading * w[:, 0] + parts[0].heading[seg] * (1 - w[:, 0])
        lift = parts[0].lift * w[:, 0]
    return PersonTrack(e, xy, heading, lift, root, ground)


def wander_path(t: np.ndarray, rng: np.random.Generator, area: float, start: np.ndarray,
                exit_route: np.ndarray | None = None, away_s: tuple[float, float] = (3.0, 6.0)) -> np.ndarray:
    """A person walking from place to place (N, 2): straight walks at their own pace between
    random points of the square ``area``, pausing 0.3-2.5 s at each. With ``exit_route`` (R, 2):
    once, at a random time in the first half of the take, they walk along the route (to a door
    and out of the room), stay away ``away_s`` seconds and come back the same way."""
    speed = rng.uniform(0.85, 1.25)
    knots_t, knots_xy = [float(t[0])], [np.asarray(start, float)]
    leave_at = t[0] + rng.uniform(0.12, 0.45) * (t[-1] - t[0]) if exit_route is not None else np.inf

    def walk_to(xy, pause):
        d = float(np.linalg.norm(xy - knots_xy[-1]))
        knots_t.append(knots_t[-1] + d / speed)
        knots_xy.append(np.asarray(xy, float))
        if pause > 0:
            knots_t.append(knots_t[-1] + pause)
            knots_xy.append(np.asarray(xy, float))

    while knots_t[-1] < t[-1]:
        if knots_t[-1] >= leave_at:
            for q in exit_route[:-1]:
                walk_to(q, 0.0)
            walk_to(exit_route[-1], rng.uniform(*away_s))
            for q in exit_route[-2::-1]:
                walk_to(q, 0.0)
            leave_at = np.inf
        walk_to(rng.uniform(-area / 2, area / 2, 2), rng.uniform(0.3, 2.5))
    kt = np.asarray(knots_t)
    kx = np.stack(knots_xy)
    xy = np.stack([np.interp(t, kt, kx[:, 0]), np.interp(t, kt, kx[:, 1])], 1)
    from scipy.ndimage import gaussian_filter1d

    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    return gaussian_filter1d(xy, 0.3 / dt, axis=0, mode="nearest")  # rounded corners, eased stops


def wander_motion(t: np.ndarray, rng: np.random.Generator, area: float, start: np.ndarray,
                  exit_route: np.ndarray | None) -> PersonTrack:
    """Walking about a room (see :func:`wander_path`) with a gait that follows the pace, the body
    turned along the way and kept when standing."""
    N = len(t)
    g = _Gen(rng, t)
    e = rest_pose(N)
    add_idle(e, g)
    set_fingers(e, "left", 0.3 + g.wiggle(0.2, (0.2, 0.6)))
    set_fingers(e, "right", 0.3 + g.wiggle(0.2, (0.2, 0.6)))
    xy = wander_path(t, rng, area, start, exit_route)
    v = np.gradient(xy, t, axis=0)
    spd = np.linalg.norm(v, axis=1)
    moving = spd > 0.15
    h = np.where(moving, heading_of(v), np.nan)
    if not moving.any():
        h[:] = rng.uniform(0, 2 * np.pi)
    idx = np.where(moving, np.arange(N), 0)
    np.maximum.accumulate(idx, out=idx)  # standing keeps the last heading walked
    h = h[idx]
    first = np.flatnonzero(moving)[0] if moving.any() else 0
    h[:first] = h[first]
    heading = np.unwrap(h)
    from scipy.ndimage import gaussian_filter1d

    dt = float(np.median(np.diff(t))) if N > 1 else 1.0
    heading = gaussian_filter1d(heading, 0.15 / dt, mode="nearest")
    phase = 2 * np.pi * np.cumsum(np.r_[0, np.diff(t)] * spd / 1.4) + rng.uniform(0, 2 * np.pi)
    lift = gait(e, phase, spd)
    return PersonTrack(e, xy, heading, lift, np.zeros((N, 3)))


# ---- two-person interactions ------------------------------------------------------------
def couple_motion(kind: str, t: np.ndarray, rng: np.random.Generator, centre: np.ndarray) -> tuple[list[PersonTrack], list[dict]]:
    """Two people interacting; returns their tracks and contact targets for refinement:
    [{"a": (person, part), "b": (person, part), "weight": (N,)}] with part in
    left_hand/right_hand/chest/back/shoulders."""
    N = len(t)
    ga, gb = _Gen(rng, t), _Gen(rng, t)
    ea, eb = rest_pose(N), rest_pose(N)
    add_idle(ea, ga, 0.6)
    add_idle(eb, gb, 0.6)
    contacts: list[dict] = []
    ones = np.ones(N)
    if kind == "couple-dance":
        # far enough that stepping feet never meet, close enough for joined hands
        dist = 0.9 + 0.06 * np.sin(2 * np.pi * 0.25 * t)
        spin = rng.choice([-1, 1]) * 0.6 * t + rng.uniform(0, 2 * np.pi)
        axis = facing(spin)
        xy_a = centre + 0.5 * dist[:, None] * axis
        xy_b = centre - 0.5 * dist[:, None] * axis
        h_a = heading_of(xy_b - xy_a)
        h_b = heading_of(xy_a - xy_b)
        phase = 2 * np.pi * 0.9 * t
        for e, sgn in ((ea, 1), (eb, -1)):
            gait(e, phase + (0 if sgn > 0 else np.pi), np.full(N, 0.45))
            # both arms forward and down, elbows bent: joined hands between the partners
            e[:, L_SHOULDER, 2] += 0.55
            e[:, R_SHOULDER, 2] += -0.55
            e[:, L_SHOULDER, 1] += -0.75
            e[:, R_SHOULDER, 1] += 0.75
            e[:, L_ELBOW, 1] += -0.6
            e[:, R_ELBOW, 1] += 0.6
            set_fingers(e, "left", 0.55)
            set_fingers(e, "right", 0.55)
        contacts.append({"a": (0, "right_hand"), "b": (1, "left_hand"), "weight": ones})
        contacts.append({"a": (0, "left_hand"), "b": (1, "right_hand"), "weight": ones})
        return [PersonTrack(ea, xy_a, h_a, np.zeros(N), np.zeros((N, 3))),
                PersonTrack(eb, xy_b, h_b, np.zeros(N), np.zeros((N, 3)))], contacts
    # the remaining interactions: face each other, partner B approaches A
    base = rng.uniform(0, 2 * np.pi)
    axis = np.repeat(facing(np.array([base]))[0][None], N, 0)
    duration = max(t[-1] - t[0], 1e-6)
    x = (t - t[0]) / duration
    if kind == "hug":
        approach = smoothstep((x - 0.1) / 0.35)
        dist = 1.3 - 0.98 * approach  # pelvis distance ends ~0.32 m (bodies touching)
        w = smoothstep((x - 0.3) / 0.25)
        for e, side in ((ea, 1), (eb, -1)):
            e[:, L_SHOULDER, 2] += 1.0 * w
            e[:, R_SHOULDER, 2] += -1.0 * w
            e[:, L_SHOULDER, 1] += -1.1 * w
            e[:, R_SHOULDER, 1] += 1.1 * w
            e[:, L_ELBOW, 1] += -1.2 * w
            e[:, R_ELBOW, 1] += 1.2 * w
            e[:, NECK, 1] += 0.5 * w * side
            set_fingers(e, "left", 0.2)
            set_fingers(e, "right", 0.2)
        contacts += [{"a": (0, "left_hand"), "b": (1, "back"), "weight": w},
                     {"a": (0, "right_hand"), "b": (1, "back"), "weight": w},
                     {"a": (1, "left_hand"), "b": (0, "back"), "weight": w},
                     {"a": (1, "right_hand"), "b": (0, "back"), "weight": w},
                     {"a": (0, "chest"), "b": (1, "chest"), "weight": w}]
    elif kind == "handshake":
        approach = smoothstep((x - 0.05) / 0.3)
        dist = 1.6 - 0.7 * approach  # ends ~0.9 m
        w = smoothstep((x - 0.25) / 0.2)
        shake = 0.12 * np.sin(2 * np.pi * 2.5 * t) * w
        for e in (ea, eb):
            e[:, R_SHOULDER, 2] += -0.4 * w
            e[:, R_SHOULDER, 1] += (0.9 + shake) * w
            e[:, R_ELBOW, 1] += 0.4 * w
            e[:, R_WRIST, 0] += 0.0
            set_fingers(e, "right", 0.45 * w + 0.2)
        contacts.append({"a": (0, "right_hand"), "b": (1, "right_hand"), "weight": w})
    else:  # push: A pushes B's chest with both hands, B steps back
        w = smoothstep((x - 0.25) / 0.15) * (1 - smoothstep((x - 0.75) / 0.15))
        dist = 0.95 + 0.25 * smoothstep((x - 0.45) / 0.3)
        for s, j in ((1, L_SHOULDER), (-1, R_SHOULDER)):
            ea[:, j, 2] += s * 0.9 * w
            ea[:, j, 1] += -s * 1.25 * w
        ea[:, L_ELBOW, 1] += -0.3 * w
        ea[:, R_ELBOW, 1] += 0.3 * w
        ea[:, SPINE1, 0] += 0.2 * w
        set_fingers(ea, "left", 0.1)
        set_fingers(ea, "right", 0.1)
        eb[:, SPINE1, 0] += -0.15 * w
        gait(eb, 2 * np.pi * 1.0 * t, 0.4 * smoothstep((x - 0.45) / 0.3) * (1 - smoothstep((x - 0.8) / 0.1)) + 0 * t)
        contacts += [{"a": (0, "left_hand"), "b": (1, "chest"), "weight": w},
                     {"a": (0, "right_hand"), "b": (1, "chest"), "weight": w}]
    xy_a = centre - 0.5 * dist[:, None] * axis
    xy_b = centre + 0.5 * dist[:, None] * axis
    h_a = heading_of(xy_b - xy_a)
    h_b = heading_of(xy_a - xy_b)
    return [PersonTrack(ea, xy_a, h_a, np.zeros(N), np.zeros((N, 3))),
            PersonTrack(eb, xy_b, h_b, np.zeros(N), np.zeros((N, 3)))], contacts


def person_centres(n: int, area: float, rng: np.random.Generator, min_dist: float = 1.4) -> np.ndarray:
    """Well-separated start positions inside a square of side ``area`` (Poisson-disc-like)."""
    pts: list[np.ndarray] = []
    for _ in range(2000):
        if len(pts) == n:
            break
        p = rng.uniform(-area / 2, area / 2, 2)
        if all(np.linalg.norm(p - q) >= min_dist for q in pts):
            pts.append(p)
    while len(pts) < n:  # area too small: fall back to a circle
        a = 2 * np.pi * len(pts) / n
        pts.append(area / 2 * np.array([np.cos(a), np.sin(a)]))
    return np.array(pts)


def separate_paths(tracks: list[PersonTrack], min_dist: float = 0.9, iters: int = 50) -> None:
    """Push walking people apart where their paths come too close (in place, smooth)."""
    P = len(tracks)
    if P < 2:
        return
    from scipy.ndimage import gaussian_filter1d

    for _ in range(iters):
        moved = False
        xy = np.stack([tr.xy for tr in tracks])  # (P, N, 2)
        d = xy[:, None] - xy[None]  # (P, P, N, 2)
        dist = np.linalg.norm(d, axis=-1) + np.eye(P)[..., None] * 1e9
        push = np.clip(min_dist - dist, 0, None)  # (P, P, N)
        if push.max() <= 1e-3:
            break
        for p in range(P):
            dirs = d[p] / np.maximum(dist[p][..., None], 1e-6)
            delta = (push[p][..., None] * dirs).sum(0) * 0.55
            if np.abs(delta).max() > 0:
                tracks[p].xy = tracks[p].xy + gaussian_filter1d(delta, 3, axis=0)
                moved = True
        if not moved:
            break


def generate_motion(kind: str, n_people: int, duration: float, rng: np.random.Generator,
                    area: float = 3.0, rate: float = 120.0, t0: float = -1.0, t1: float | None = None,
                    exit_routes: list[np.ndarray] | None = None, leave: int = 0,
                    ) -> tuple[list[PersonTrack], np.ndarray, list[dict]]:
    """Person tracks sampled at ``rate`` Hz over scene time [t0, t1] (default: the clip plus
    margins for cameras that start early or stop late). ``wander``: ``leave`` of the people walk
    out along one of ``exit_routes`` (each (R, 2) way points from inside the room to outside)
    once and come back."""
    t1 = duration + 0.5 if t1 is None else t1
    t = np.arange(t0, t1 + 0.5 / rate, 1.0 / rate)
    if kind in ("couple-dance", "hug", "handshake", "push"):
        tracks, contacts = couple_motion(kind, t, rng, rng.uniform(-0.3, 0.3, 2))
        return tracks, t, contacts
    centres = person_centres(n_people, area, rng) if n_people > 1 else rng.uniform(-0.2, 0.2, (1, 2))
    if kind == "wander":  # some people leave through a door (exit_routes) and come back
        routes = list(exit_routes or [])
        leavers = set(rng.permutation(n_people)[:min(leave, n_people)].tolist()) if routes else set()
        tracks = [wander_motion(t, rng, area, centres[p],
                                routes[int(rng.integers(len(routes)))] if p in leavers else None)
                  for p in range(n_people)]
        separate_paths(tracks)
        return tracks, t, []
    kinds = [kind] * n_people
    if kind == "crowd":
        kinds = [rng.choice(["walk", "walk", "gestures", "squat", "turn", "jump"]) for _ in range(n_people)]
    tracks = []
    for p in range(n_people):
        face = heading_of(-centres[p]) if np.linalg.norm(centres[p]) > 0.3 else rng.uniform(0, 2 * np.pi)
        area_p = area if n_people == 1 else area / max(np.sqrt(n_people), 1.5)
        tracks.append(single_motion(kinds[p], t, rng, centres[p], area_p, face))
    separate_paths(tracks)
    return tracks, t, []
