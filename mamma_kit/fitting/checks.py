"""Physical self-checks of a fit: what no real body can be, found per person and frame and said
with its likely cause, beside the result (fit_report.json "checks") and in the report.

A small reprojection error says little when a person was fitted from wrongly matched tracks: the
wrong pair triangulates somewhere and the fit follows it there. These checks read only the fitted
bodies, the rig and which views saw whom:

impossible (a body cannot be so; ``passed`` is false):
- ``inside_camera``: a joint within ``near_camera_m`` of a camera's centre;
- ``behind_camera``: a camera that sees the person has the pelvis behind it (or nearly at it);
- ``below_floor``: the lowest joint well under the floor, where calibration found the floor;
- ``too_fast``: the pelvis faster than a sprinter between two fitted frames;
- ``same_place``: two persons' pelvises closer than two bodies can be;
doubtful (possible, but worth a look):
- ``floating``: the lowest joint high above the floor for longer than a jump;
- ``height``: a rest-pose body height outside what adults and children measure;
- ``depth``: seen by two views only, whose rays to the person are nearly parallel (depth along
  them is poorly determined);
- ``unseen``: a camera looks at where the person is (in front, inside its image) for most of
  the take but has no track of them there.

Each flag names the person, the frames (runs of consecutive fitted frames), the check, what was
measured and the likely cause.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

IMPOSSIBLE = ("inside_camera", "behind_camera", "below_floor", "too_fast", "same_place")
DOUBTFUL = ("floating", "height", "depth", "unseen", "view_swapped", "view_clock", "view_pose", "view_disagrees")
MAX_RUNS = 12  # per person and check: the longest runs are listed, the rest counted


@dataclass(frozen=True)
class Limits:
    near_camera_m: float = 0.3  # a joint this close to a camera's centre is inside it
    min_depth_m: float = 0.2  # a seen pelvis nearer than this in front of the camera (or behind it)
    below_floor_m: float = 0.15  # lowest joint this far under z = 0
    floating_m: float = 0.6  # lowest joint this high above the floor ...
    floating_s: float = 1.0  # ... for this long (a jump lasts well under a second)
    max_speed_mps: float = 8.0  # the pelvis of a sprinter peaks near 10 m/s; people on foot stay under 7
    same_place_m: float = 0.2  # two pelvises this close: one body, or two bodies inside each other
    height_m: tuple = (1.0, 2.3)  # rest-pose height of the fitted shape
    parallel_deg: float = 12.0  # two views' rays to the person closer than this: depth poorly known
    unseen_share: float = 0.5  # a camera that should see the person in this share of their frames ...
    unseen_margin: float = 0.05  # ... (inside its image by this share of its size) and has no track of them


def runs(mask_t: np.ndarray) -> list[tuple[int, int]]:
    """Runs of True as (first, last) indices."""
    m = np.r_[False, np.asarray(mask_t, bool), False]
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b) - 1) for a, b in zip(d[::2], d[1::2])]


class _Flags:
    def __init__(self, times_t: np.ndarray, person_ids: list[int]):
        self.times, self.pids, self.items, self.counts = times_t, person_ids, [], {}

    def add(self, p: int, check: str, mask_t: np.ndarray, what, cause: str) -> None:
        """One flag per run of frames in mask_t; ``what(a, b)`` says what was measured in a run."""
        rs = runs(mask_t)
        if not rs:
            return
        self.counts[check] = self.counts.get(check, 0) + int(np.sum(mask_t))
        rs.sort(key=lambda r: r[0] - r[1])  # longest first
        for a, b in sorted(rs[:MAX_RUNS]):
            self.items.append({"person": int(self.pids[p]), "check": check,
                               "severity": "impossible" if check in IMPOSSIBLE else "doubtful",
                               "frames": [a, b], "times_s": [float(self.times[a]), float(self.times[b])],
                               "what": what(a, b), "cause": cause})
        if len(rs) > MAX_RUNS:
            self.items[-1]["more_runs"] = len(rs) - MAX_RUNS


def check_fit(joints_ptj3: np.ndarray, observed_pt: np.ndarray, seen_cpt: np.ndarray, times_t: np.ndarray,
              rig, floor_known: bool, heights_p: np.ndarray, person_ids: list[int],
              limits: Limits = Limits(), views=()) -> dict:
    """Every check on every fitted person and frame (see module doc).

    joints_ptj3: (P, T, 55, 3) world joints; observed_pt: (P, T) frames the person was fitted from
    views; seen_cpt: (C, P, T) which camera saw whom (rig order); heights_p: (P,) rest-pose heights (m); views:
    fitting.viewcheck's findings (each camera against the fitted bodies), added as flags.
    Returns {"passed", "impossible_frames", "doubtful_frames", "by_check", "flags": [...], "limits"}.
    """
    L = limits
    P, T = observed_pt.shape
    fl = _Flags(np.asarray(times_t, float), person_ids)
    pelvis = joints_ptj3[:, :, 0]
    centres = rig.centers()
    names = rig.names
    for p in range(P):
        obs = observed_pt[p]
        seen_by = lambda a, b: ", ".join(n for c, n in enumerate(names) if seen_cpt[c, p, a:b + 1].any())  # noqa: E731
        # inside a camera: any joint near any centre
        d_ct = np.linalg.norm(joints_ptj3[p][None] - centres[:, None, None], axis=-1).min(-1)  # (C, T)
        for c, n in enumerate(names):
            near = obs & (d_ct[c] < L.near_camera_m)
            fl.add(p, "inside_camera", near,
                   lambda a, b, c=c, n=n: f"a joint {d_ct[c, a:b + 1].min():.2f} m from {n}'s centre",
                   f"the tracks matched into this person are probably two different people (seen by "
                   f"{seen_by(0, T - 1)}), or {n}'s calibration is wrong")
        # behind (or at) a camera that sees them
        for c, n in enumerate(names):
            depth = rig[n].to_camera(pelvis[p])[:, 2]
            bad = obs & seen_cpt[c, p] & (depth < L.min_depth_m)
            fl.add(p, "behind_camera", bad, lambda a, b, depth=depth, n=n:
                   f"{n} sees the person, but the pelvis is {depth[a:b + 1].min():+.2f} m along its view",
                   f"a wrong match in {n} (its track is another person), or {n}'s pose in calibration.toml is wrong")
        lowest = joints_ptj3[p, :, :, 2].min(-1)
        if floor_known:
            fl.add(p, "below_floor", obs & (lowest < -L.below_floor_m),
                   lambda a, b: f"lowest joint {lowest[a:b + 1].min():.2f} m under the floor",
                   "the views matched into this person disagree (a wrong match lands under the floor), or the "
                   "floor in calibration.toml is off")
            high = obs & (lowest > L.floating_m)
            long_high = np.zeros(T, bool)
            for a, b in runs(high):
                if times_t[b] - times_t[a] >= L.floating_s:
                    long_high[a:b + 1] = True
            fl.add(p, "floating", long_high,
                   lambda a, b: f"lowest joint {lowest[a:b + 1].min():.2f} m or more above the floor for "
                                f"{times_t[b] - times_t[a]:.1f} s",
                   "a wrong match or a wrong floor (or the person stands on furniture)")
        # speed between consecutive fitted frames
        idx = np.flatnonzero(obs)
        if len(idx) > 1:
            dt = np.diff(times_t[idx])
            v = np.linalg.norm(np.diff(pelvis[p, idx], axis=0), axis=-1) / np.maximum(dt, 1e-6)
            fast = np.zeros(T, bool)
            speed = np.zeros(T)
            fast[idx[1:]] = v > L.max_speed_mps
            speed[idx[1:]] = v
            fl.add(p, "too_fast", fast, lambda a, b: f"pelvis at {speed[a:b + 1].max():.1f} m/s",
                   "a track switches person between these frames (identities.json), or a camera's clock (timing.toml) "
                   "or pose (calibration.toml) is off: see the view checks")
        # two views only, nearly parallel rays
        n_seen = seen_cpt[:, p].sum(0)
        two = obs & (n_seen == 2)
        if two.any():
            ang = np.full(T, 180.0)
            for t in np.flatnonzero(two):
                cs = np.flatnonzero(seen_cpt[:, p, t])
                r0, r1 = pelvis[p, t] - centres[cs[0]], pelvis[p, t] - centres[cs[1]]
                cosv = r0 @ r1 / (np.linalg.norm(r0) * np.linalg.norm(r1) + 1e-12)
                ang[t] = np.degrees(np.arccos(np.clip(cosv, -1, 1)))
            fl.add(p, "depth", two & (ang < L.parallel_deg),
                   lambda a, b: f"seen by {seen_by(a, b)} only, their rays {ang[a:b + 1].min():.0f} deg apart",
                   "depth along those views is poorly determined: the body may be too near or too far")
        # a camera that should see the person and has no track of them
        for c, n in enumerate(names):
            cam = rig[n]
            xy = cam.project(pelvis[p])
            depth = cam.to_camera(pelvis[p])[:, 2]
            mw, mh = L.unseen_margin * cam.width, L.unseen_margin * cam.height
            inside = (depth > 0.5) & (xy[:, 0] > mw) & (xy[:, 0] < cam.width - mw) & (xy[:, 1] > mh) & \
                (xy[:, 1] < cam.height - mh)
            should = obs & inside & (n_seen >= 2) & ~seen_cpt[c, p]
            if should.sum() >= max(10, L.unseen_share * obs.sum()):
                fl.add(p, "unseen", should, lambda a, b, n=n: f"{n} looks at the person but has no track of them",
                       f"{n} missed them (occluded, or the tracker lost them: `mamma-kit fill`), or the body is not "
                       "where the person is")
        h = float(heights_p[p])
        if not L.height_m[0] <= h <= L.height_m[1]:
            fl.add(p, "height", obs, lambda a, b, h=h: f"body {h:.2f} m tall",
                   "the shape was fitted from wrongly matched views or too few frames")
    # two persons in one place
    for p in range(P):
        for q in range(p + 1, P):
            both = observed_pt[p] & observed_pt[q]
            d = np.linalg.norm(pelvis[p] - pelvis[q], axis=-1)
            fl.add(p, "same_place", both & (d < L.same_place_m),
                   lambda a, b, d=d, q=q: f"pelvis {d[a:b + 1].min():.2f} m from person {person_ids[q]}'s",
                   "one person fitted twice: tracks of one person were matched into two persons")
    for f in views:
        fl.add(f.person, f.check, f.frames_t, lambda a, b, w=f.what: w, f.cause)
    impossible = sum(v for k, v in fl.counts.items() if k in IMPOSSIBLE)
    return {"passed": impossible == 0, "impossible_frames": int(impossible),
            "doubtful_frames": int(sum(v for k, v in fl.counts.items() if k in DOUBTFUL)),
            "by_check": {k: int(v) for k, v in sorted(fl.counts.items())}, "flags": fl.items,
            "floor_known": bool(floor_known), "limits": asdict(L)}


def rest_heights(model, betas_pb: np.ndarray) -> np.ndarray:
    """(P,) standing height (m) of each fitted shape: the rest mesh's extent along the body's up axis."""
    v = model.np.v_template.astype(np.float64)
    dirs = model.np.shapedirs.astype(np.float64)
    B = model.num_betas
    out = []
    for b in np.asarray(betas_pb, np.float64):
        y = v[:, 1] + dirs[:, 1, :B] @ b[:B]
        out.append(float(y.max() - y.min()))
    return np.array(out)


def summary_lines(checks: dict, limit: int = 8) -> list[str]:
    """Lines for a terminal: each flag, impossible ones first, at most ``limit``."""
    items = sorted(checks.get("flags", []), key=lambda f: (f["severity"] != "impossible", f["person"], f["frames"][0]))
    out = [f"person {f['person']}, frames {f['frames'][0]}-{f['frames'][1]} ({f['times_s'][0]:.2f}-"
           f"{f['times_s'][1]:.2f} s): {f['check'].replace('_', ' ')}: {f['what']}: {f['cause']}"
           for f in items[:limit]]
    if len(items) > limit:
        out.append(f"... and {len(items) - limit} more in smplx/fit_report.json (\"checks\")")
    return out
