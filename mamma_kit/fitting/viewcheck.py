"""Which view disagrees with the fitted bodies, and the fault that explains it.

A view whose tracks, clock or pose are wrong does not always give an impossible body: with three
or more views the fit sets such a view aside where its keypoints miss the others' consensus, and
the body stays where the other views put it. The fault is still in the user's files. So each
camera's landmarks are compared with the fitted bodies projected into it, and three faults a user
can make are tried on it, each a change of one file:

- ``view_swapped``: its tracks of two persons exchanged (identities.json): in a run of frames the
  other person's body fits its landmarks far better than their own;
- ``view_clock``: its clock off (timing.toml): the people in it move as in the other views some
  frames earlier or later (timing.crosscheck on the fit's keypoints: the fit absorbs a late view,
  bending its bodies towards it, so the bodies cannot tell);
- ``view_pose``: its pose off (calibration.toml): a pose solved from the bodies (PnP on the
  fitted landmarks and its observed ones) fits far better, some distance from the calibrated one;
- ``view_disagrees``: it lands far from the bodies and none of the three explains it.

Only cameras that share their people with two or more other views are judged (with two views the
bodies are as much this view's work as the other's). A pose is tried on the odd camera out only:
the one without which the other views agree best (each left out in turn, the bodies moved per
person and frame to fit the rest), on a sample of blocks of frames. Arrays: C cameras (rig order),
P persons, T frames, S landmarks (an evenly spread subset of the fit's), J = 33 keypoints.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from mamma_kit.core.camera import rotvec
from mamma_kit.fitting.checks import runs

SUBSET = 32  # landmarks per body used here: enough for a median, small for a take of minutes
MIN_POINTS = 6  # a person-frame's error needs this many visible landmarks
MIN_FRAMES = 10  # person-frames a camera needs to be judged
GAIN = 0.7  # a fault explains a view when it brings the view's median error to this share or less
SWAP_SHARE = 0.5  # ... per frame, for a swap: the other person's body at this share of their own
SWAP_RUN = 3  # frames: a shorter run of a better-fitting other person is noise
CLOCK_WINDOW_S = 20.0  # the clocks are checked on this much of the take's middle (an offset shows in any)
MIN_MOVE = (0.1, 1.0)  # m, deg: a solved pose nearer than both to the calibrated one is the same pose
PNP_INLIER_PX = 8.0  # RANSAC's inlier distance for the pose solved from the bodies
DISAGREE = (2.5, 3.0)  # a view is off when its median error exceeds both x the others' and + px
ODD_SHARE = 0.8  # the odd camera: without it the others agree to this share of the typical leave-one-out
SAMPLE_BLOCKS, SAMPLE_LENGTH = 8, 40  # frames for the camera-wide tests on a long take


@dataclass
class ViewFinding:
    """One fault found in one camera for one person (index into the fitted persons), over frames."""

    person: int
    check: str
    frames_t: np.ndarray  # (T,) bool
    what: str
    cause: str


def landmark_subset(n_landmarks: int, n: int = SUBSET) -> np.ndarray:
    return np.unique(np.linspace(0, n_landmarks - 1, min(n, n_landmarks)).round().astype(int))


def gather(model, blocks, pose_ptj3: np.ndarray, transl_pt3: np.ndarray, betas_pb: np.ndarray,
           min_vis: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """The fitted bodies' landmarks (P, T, S, 3) and each camera's observed ones (C, P, T, S, 2)
    (NaN where not visible), from ``blocks``: (frame slice, FitData of those frames) over the take."""
    import torch

    from mamma_kit.body.lbs import pose_restricted
    from mamma_kit.fitting.energies import pose_dict

    P, T = transl_pt3.shape[:2]
    world = obs = None
    sub = None
    for s, d in blocks:
        if sub is None:
            sub = landmark_subset(d.xy.shape[3])
            world = np.full((P, T, len(sub), 3), np.nan, np.float32)
            obs = np.full((d.xy.shape[0], P, T, len(sub), 2), np.nan, np.float32)
        with torch.no_grad():
            v, _ = pose_restricted(model, pose_dict(torch.as_tensor(pose_ptj3[:, s], dtype=torch.float32),
                                                    torch.as_tensor(transl_pt3[:, s], dtype=torch.float32),
                                                    torch.as_tensor(betas_pb, dtype=torch.float32)),
                                   vertex_ids=np.asarray(model.landmark_ids)[sub])
        world[:, s] = v.numpy()
        seen = (d.vis[:, :, :, sub] > min_vis) & d.present[..., None]
        obs[:, :, s] = np.where(seen[..., None], d.xy[:, :, :, sub], np.nan)
    return world, obs


def frame_errors(camera, world_ptS3: np.ndarray, obs_ptS2: np.ndarray) -> np.ndarray:
    """(P, T) median px between a camera's observed landmarks and the bodies projected into it;
    NaN where fewer than MIN_POINTS are seen (or the body is behind the camera)."""
    uv = camera.project(world_ptS3.reshape(-1, 3)).reshape(*world_ptS3.shape[:-1], 2)
    e = np.linalg.norm(uv - obs_ptS2, axis=-1)
    ok = np.isfinite(e)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: NaN, as wanted
        med = np.nanmedian(e, -1)
    return np.where(ok.sum(-1) >= MIN_POINTS, med, np.nan)


def bodies_without(rig, world_ptS3: np.ndarray, obs_cptS2: np.ndarray, c: int, huber_px: float = 5.0,
                   iters: int = 3) -> np.ndarray:
    """The bodies (P, T, S, 3) each moved by the translation (per person and frame) that best fits
    every view but camera ``c`` (Gauss-Newton with Huber weights on their landmarks, the fit's own
    projection Jacobians); unmoved where fewer than two of those views see the person."""
    import torch

    from mamma_kit.fitting.projection import RigTensors

    cams = RigTensors.from_rig(rig)
    others = np.arange(len(rig.names)) != c
    obs = obs_cptS2[others]  # (C-1, P, T, S, 2)
    seen = np.isfinite(obs).all(-1)
    use = (seen.sum(-1) >= MIN_POINTS).sum(0) >= 2  # (P, T)
    delta = np.zeros(world_ptS3.shape[:2] + (3,))
    for _ in range(iters):
        X = torch.as_tensor(world_ptS3 + delta[:, :, None], dtype=torch.float64)[None]
        uv, J, valid = (a.numpy()[others] for a in cams.project_jacobian(X))
        r = obs - uv
        ok = seen & valid
        rz = np.where(ok[..., None], r, 0.0)
        w = np.where(ok, np.minimum(1.0, huber_px / np.maximum(np.linalg.norm(rz, axis=-1), 1e-9)), 0.0)
        A = np.einsum("cptsia,cptsib,cpts->ptab", J, J, w)
        b = np.einsum("cptsia,cptsi,cpts->pta", J, rz, w)
        A += 1e-6 * np.eye(3) * (np.trace(A, axis1=-2, axis2=-1)[..., None, None] + 1e-9)
        delta[use] += np.linalg.solve(A[use], b[use][..., None])[..., 0]
    return world_ptS3 + delta[:, :, None]


def _median(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.median(a)) if len(a) else np.nan


def _runs_at_least(mask_t: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros_like(mask_t)
    for a, b in runs(mask_t):
        if b - a + 1 >= n:
            out[a:b + 1] = True
    return out


def solve_pose(camera, world_n3: np.ndarray, obs_n2: np.ndarray):
    """The camera with its pose re-solved from world points and their observed pixels (PnP from
    the calibrated pose, on undistorted normalised coordinates: any lens model)."""
    import cv2

    xn = camera.pixels_to_lens(obs_n2.astype(np.float64))
    X = world_n3.astype(np.float64)
    rvec0 = cv2.Rodrigues(camera.R)[0]
    # RANSAC: a landmark the network misplaced (or a frame the fit got wrong) must not pull the pose
    ok, rvec, tvec, inl = cv2.solvePnPRansac(X, xn, np.eye(3), None, rvec0.copy(),
                                             camera.t.reshape(3, 1).astype(np.float64).copy(), useExtrinsicGuess=True,
                                             iterationsCount=200, reprojectionError=PNP_INLIER_PX / camera.K[0, 0],
                                             confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok or inl is None or len(inl) < 6:
        return None
    rvec, tvec = cv2.solvePnPRefineLM(X[inl[:, 0]], xn[inl[:, 0]], np.eye(3), None, rvec, tvec)
    return camera.copy(R=cv2.Rodrigues(rvec)[0], t=tvec.reshape(3))


def view_findings(rig, world_ptS3: np.ndarray, obs_cptS2: np.ndarray, person_ids: list[int],
                  max_points: int = 20000) -> list[ViewFinding]:
    """Every camera judged against the fitted bodies (see module doc; the clocks: clock_findings)."""
    names = rig.names
    C, P, T = obs_cptS2.shape[:3]
    seen_cpt = np.isfinite(obs_cptS2).any(-1).sum(-1) >= MIN_POINTS
    e_cpt = np.stack([frame_errors(rig[n], world_ptS3, obs_cptS2[c]) for c, n in enumerate(names)])
    med = np.array([_median(e_cpt[c]) for c in range(C)])
    out: list[ViewFinding] = []
    judged: dict[int, tuple[np.ndarray, float]] = {}
    for c, n in enumerate(names):
        # judged only where two or more other views share the person
        ok = seen_cpt[c] & (seen_cpt.sum(0) - seen_cpt[c] >= 2) & np.isfinite(e_cpt[c])
        if ok.sum() < MIN_FRAMES:
            continue
        ref = _median(np.delete(med, c))
        swapped, found = swap_findings(rig[n], world_ptS3, obs_cptS2[c], e_cpt[c], ok, ref, person_ids)
        out += found
        if swapped[ok].mean() < 0.5:  # else the swap explains the view
            judged[c] = (ok & ~swapped, ref)
    sel = sample_frames(T)
    odd, bodies = odd_camera(rig, world_ptS3[:, sel], obs_cptS2[:, :, sel], list(judged))
    for c, (rest, ref) in judged.items():
        n = rig.names[c]
        found = []
        if c == odd:
            found = pose_finding(rig[n], bodies, obs_cptS2[c][:, sel], rest[:, sel], max_points)
        base = _median(np.where(rest, e_cpt[c], np.nan))
        if not found and base > max(DISAGREE[0] * ref, ref + DISAGREE[1]):
            found = [("view_disagrees", f"{n}'s landmarks lie a median {base:.0f} px from the fitted bodies, the "
                                        f"other views' {ref:.0f} px",
                      f"{n}'s tracks, clock or calibration are off (neither a swap, a clock offset nor a moved "
                      f"camera explains it)")]
        for check, what, cause in found:
            out += [ViewFinding(p, check, _span(rest[p]), what.replace("CAM", n), cause.replace("CAM", n))
                    for p in range(P) if rest[p].any()]
    return out


def swap_findings(cam, world_ptS3, obs_ptS2, e_pt, judged_pt, ref: float, person_ids) -> tuple[np.ndarray, list]:
    """Runs of frames in which another person's body fits this view's landmarks of a person far
    better than their own: (P, T) frames explained so, and their findings."""
    P, T = e_pt.shape
    swapped = np.zeros((P, T), bool)
    out = []
    for p in range(P):
        for q in range(P):
            if q == p:
                continue
            eq = frame_errors(cam, world_ptS3[q], obs_ptS2[p])
            with np.errstate(invalid="ignore"):
                m = _runs_at_least(judged_pt[p] & (eq < SWAP_SHARE * e_pt[p]) & (e_pt[p] > ref + DISAGREE[1]),
                                   SWAP_RUN)
            if m.any():
                swapped[p] |= m
                out.append(ViewFinding(p, "view_swapped", m,
                                       f"{cam.name}'s landmarks of this person fit person {person_ids[q]}'s body "
                                       f"({_median(eq[m]):.0f} px) better than their own "
                                       f"({_median(e_pt[p][m]):.0f} px)",
                                       f"{cam.name}'s tracks of persons {person_ids[p]} and {person_ids[q]} are "
                                       f"swapped here (identities.json: a wrong match)"))
    return swapped, out


def sample_frames(T: int, blocks: int = SAMPLE_BLOCKS, length: int = SAMPLE_LENGTH) -> np.ndarray:
    """Frames for the camera-wide tests: the whole take, or blocks of consecutive frames spread over it
    (a clock offset shows within a block; a take of minutes costs no more than a few seconds)."""
    if T <= blocks * length:
        return np.arange(T)
    starts = np.linspace(0, T - length, blocks).round().astype(int)
    return np.unique((starts[:, None] + np.arange(length)).ravel())


def odd_camera(rig, world_ptS3, obs_cptS2, candidates: list[int]) -> tuple[int | None, np.ndarray | None]:
    """The camera whose views disagree with the others': the one without which the other views agree
    best (each candidate left out in turn, the bodies moved to fit the rest), if it stands out; and
    the bodies as the other views place them."""
    if len(candidates) < 2:
        return None, None
    resid, bodies = {}, {}
    for c in candidates:
        bodies[c] = bodies_without(rig, world_ptS3, obs_cptS2, c)
        others = [_median(frame_errors(rig[rig.names[o]], bodies[c], obs_cptS2[o])) for o in range(len(rig.names))
                  if o != c]
        resid[c] = _median(np.array(others))
    best = min(resid, key=resid.get)
    if not resid[best] < ODD_SHARE * _median(np.array(list(resid.values()))):
        return None, None
    return best, bodies[best]


def pose_finding(cam, world_ptS3, obs_ptS2, rest_pt, max_points: int) -> list:
    """A moved camera that explains a view's landmarks against the bodies the other views place:
    [(check, what, cause)] with CAM for the camera, or []."""
    e_pt = frame_errors(cam, world_ptS3, obs_ptS2)
    base = _median(np.where(rest_pt, e_pt, np.nan))
    pick = np.nonzero(rest_pt[..., None] & np.isfinite(obs_ptS2).all(-1) & np.isfinite(world_ptS3).all(-1))
    e_pose, moved = np.inf, (0.0, 0.0)
    if len(pick[0]) >= 6 * MIN_POINTS:
        use = np.linspace(0, len(pick[0]) - 1, min(max_points, len(pick[0]))).round().astype(int)
        idx = tuple(a[use] for a in pick)
        solved = solve_pose(cam, world_ptS3[idx], obs_ptS2[idx])
        if solved is not None:
            e_pose = _median(np.where(rest_pt, frame_errors(solved, world_ptS3, obs_ptS2), np.nan))
            moved = (float(np.linalg.norm(solved.center - cam.center)),
                     float(np.degrees(np.linalg.norm(rotvec(solved.R @ cam.R.T)))))
    if e_pose < GAIN * base and (moved[0] >= MIN_MOVE[0] or moved[1] >= MIN_MOVE[1]):
        return [("view_pose", f"a pose of CAM solved from the bodies the other views place fits its landmarks at "
                              f"{e_pose:.0f} px, its calibrated pose at {base:.0f} px (the solved one "
                              f"{moved[0]:.2f} m / {moved[1]:.1f} deg away)",
                 "CAM's pose in calibration.toml is off (the camera moved after the board session, or the board "
                 "did not tie it to the others): calibrate again, or refine the poses from the people "
                 "(`mamma-kit calibrate WORKSPACE --people`)")]
    return []


def clock_findings(rig, times_t: np.ndarray, kp_xy_cptj2: np.ndarray, kp_vis_cptj: np.ndarray,
                   person_ids: list[int], window_s: float = CLOCK_WINDOW_S) -> list[ViewFinding]:
    """Cameras whose clock the others' motion disagrees with (timing.crosscheck), from the fit's
    keypoints on the reference clock (0 visibility where a view does not see a person): one finding
    per person the camera sees."""
    from mamma_kit.timing.crosscheck import clocks_off

    T = len(times_t)
    mid = 0.5 * (times_t[0] + times_t[-1]) if T else 0.0
    win = np.flatnonzero(np.abs(times_t - mid) <= 0.5 * window_s)
    if len(win) < 2:
        return []
    seen_cpt = kp_vis_cptj.max(-1) > 0
    kp_xy_cptj2 = np.where((kp_vis_cptj > 0)[..., None], kp_xy_cptj2, np.nan)  # the fit's 0 px where unseen
    points = {n: (rig[n], times_t[win], kp_xy_cptj2[c][:, win].transpose(1, 0, 2, 3),  # persons as tracks
                  kp_vis_cptj[c][:, win].transpose(1, 0, 2), seen_cpt[c][:, win].T) for c, n in enumerate(rig.names)}
    out = []
    for off in clocks_off(points):
        c, o = rig.names.index(off.camera), off.offset_s
        what = (f"{off.camera}'s frames show the people as the other views do {abs(o):.2f} s "
                f"{'earlier' if o < 0 else 'later'} than timing.toml times them (against "
                + ", ".join(f"{n} {v:+.2f} s" for n, v in off.pairs_s.items())
                + f"; the other views agree within {off.others_s:.2f} s)")
        cause = (f"{off.camera}'s clock in timing.toml is off by about {abs(o):.2f} s: check the sync "
                 f"(`mamma-kit sync`, the report's sync plots), or sync by a clap, LTC or a flash")
        out += [ViewFinding(p, "view_clock", _span(seen_cpt[c, p]), what, cause)
                for p in range(len(person_ids)) if seen_cpt[c, p].any()]
    return out


def camera_findings(rig, world_ptS3: np.ndarray, obs_cptS2: np.ndarray, person_ids: list[int], times_t: np.ndarray,
                    kp_xy_cptj2: np.ndarray | None, kp_vis_cptj: np.ndarray | None) -> list[ViewFinding]:
    """Every camera judged: against the fitted bodies (view_findings) and its clock against the
    others' (clock_findings, where the fit has keypoints)."""
    out = view_findings(rig, world_ptS3, obs_cptS2, person_ids)
    if kp_xy_cptj2 is not None:
        out += clock_findings(rig, times_t, kp_xy_cptj2, kp_vis_cptj, person_ids)
    return out


def _span(mask_t: np.ndarray) -> np.ndarray:
    """One run from the first to the last True (a camera's fault is one finding, not one per gap)."""
    out = np.zeros_like(mask_t)
    i = np.flatnonzero(mask_t)
    if len(i):
        out[i[0]:i[-1] + 1] = True
    return out
