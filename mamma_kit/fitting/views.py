"""Views whose keypoints disagree with the other views: a person's whole reading there set aside.

A keypoint detector that loses a person behind someone else, or follows the wrong person, in one
view gives points that are self-consistent in that image but meet no ray of the other views; and
the keypoint-guided landmarks of that crop follow them. The fit's robust losses only down-weight
points one by one, and a whole view that is wrong together still pulls (the demo: one dancer
partly behind the other in cam3 for about 40 frames, where BlazePose loses her).

Per person and frame, each pair of views that both see a body point triangulates the body points
(``CONSENSUS_POINTS``); every view's median reprojection error under that pair, as a fraction of
the person's size in the view, says whether it agrees. The pair with the most agreeing views (then
the smallest error) is the consensus; a view outside it loses its keypoints and hand points for
that frame when at least two views agree without it (with two views in all, neither can be told
wrong), and its landmarks too where they are off the consensus as well (a keypoint-guided network
follows the detector; landmarks of another source, right where BlazePose failed, stay).
"""

from __future__ import annotations

import dataclasses
import warnings
from itertools import combinations

import numpy as np

from mamma_kit.core.camera import Rig
from mamma_kit.fitting.init import rays, solve_rays

# BlazePose's nose, shoulders, elbows, wrists, hips, knees, ankles: points every view reads alike
CONSENSUS_POINTS = (0, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)
MIN_POINTS = 4  # body points a view must share with a pair to be judged


def view_errors(rig: Rig, xy_cptn2: np.ndarray, w_cptn: np.ndarray, size_cpt: np.ndarray) -> np.ndarray:
    """Median reprojection error (fraction of the person's size in the view) of every view under
    every pair's triangulation: (pairs, C, P, T), NaN where the view or the pair sees too little.

    xy (C, P, T, N, 2) px, w (C, P, T, N) 1 where a point is read, size (C, P, T) px."""
    C = len(rig)
    centres, dirs = rays(rig, xy_cptn2)
    seen = w_cptn > 0
    out = []
    for a, b in combinations(range(C), 2):
        both = seen[a] & seen[b]  # (P, T, N)
        X, _ = solve_rays(centres[[a, b]], dirs[[a, b]], np.stack([both, both]).astype(np.float64), axis=0)
        proj = rig.project(X)  # (C, P, T, N, 2)
        e = np.linalg.norm(proj - xy_cptn2, axis=-1) / np.maximum(size_cpt, 1.0)[..., None]
        ok = seen & both[None] & np.isfinite(e)
        e = np.where(ok, e, np.nan)
        with warnings.catch_warnings():  # a view that sees none of the pair's points: NaN, no warning
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(e, -1)
        out.append(np.where(ok.sum(-1) >= MIN_POINTS, med, np.nan))
    return np.stack(out) if out else np.zeros((0, C) + size_cpt.shape[1:])


def consensus(E: np.ndarray, frac: float) -> tuple[np.ndarray, np.ndarray]:
    """The consensus pair per person and frame from ``view_errors`` E (pairs, C, P, T): the pair
    most views agree with (error <= frac), then the least mean error among them. Returns its index
    (P, T) and how many views agree with it (P, T)."""
    agree = E <= frac  # NaN compares False
    n_agree = agree.sum(1)  # (Q, P, T)
    err = np.where(agree, E, 0.0).sum(1)
    score = n_agree - 0.5 * err / (np.maximum(n_agree, 1) * frac)  # the error term stays below 1
    best = np.argmax(score, 0)
    return best, np.take_along_axis(n_agree, best[None], 0)[0]


def at_pair(E: np.ndarray, best: np.ndarray) -> np.ndarray:
    """(C, P, T) errors of every view under pair ``best`` (P, T) of E (pairs, C, P, T)."""
    return np.take_along_axis(E, best[None, None], 0)[0]


def inconsistent_views(rig: Rig, kp_xy: np.ndarray, kp_vis: np.ndarray, kp_size: np.ndarray,
                       frac: float, min_vis: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Views whose body points (``CONSENSUS_POINTS`` seen above ``min_vis``) miss the consensus of
    the others by more than ``frac`` of the person's size (see module doc): flags (C, P, T) bool and
    the consensus pair (P, T) (an index into ``view_errors``' pairs). kp_xy (C, P, T, 33, 2),
    kp_vis (C, P, T, 33), kp_size (C, P, T)."""
    C, P, T = kp_vis.shape[:3]
    if C < 3 or frac <= 0:
        return np.zeros((C, P, T), bool), np.zeros((P, T), np.int64)
    pts = list(CONSENSUS_POINTS)
    w = (kp_vis[..., pts] > min_vis).astype(np.float64)
    E = view_errors(rig, kp_xy[..., pts, :].astype(np.float64), w, kp_size.astype(np.float64))
    best, n_best = consensus(E, frac)
    return (at_pair(E, best) > frac) & (n_best >= 2)[None], best  # NaN (too little seen) compares False


def spread_subset(points_n3: np.ndarray, n: int) -> np.ndarray:
    """Indices of ``n`` points spread over a point set (farthest-point sampling from point 0)."""
    sel = [0]
    dmin = np.linalg.norm(points_n3 - points_n3[0], axis=1)
    for _ in range(min(n, len(points_n3)) - 1):
        i = int(np.argmax(dmin))
        sel.append(i)
        dmin = np.minimum(dmin, np.linalg.norm(points_n3 - points_n3[i], axis=1))
    return np.array(sel, np.int64)


def set_aside_flags(data, frac: float, landmark_subset: np.ndarray | None = None, lm_min_vis: float = 0.2):
    """``data`` (FitData) with the weights of inconsistent views at 0 for those frames, and the flags
    (C, P, T): views whose keypoints and hand points were set aside, and whose landmarks were.

    Keypoints and hand points go where BlazePose's body points miss the consensus
    (``inconsistent_views``); the landmarks with them only where they too are off it: the
    ``landmark_subset``'s landmarks (visibility above ``lm_min_vis``) more than ``frac`` / 4 from
    the consensus pair's triangulation (a keypoint-guided network follows BlazePose off the
    person; landmarks from elsewhere, or too few seen to tell, stay). Without a subset, the
    landmarks go with the keypoints. The data is returned as it is without keypoints, with fewer
    than three cameras or ``frac`` 0. Every frame is judged on its own, so a chunk of frames gets
    the flags the whole take has there."""
    none = np.zeros(data.present.shape, bool)
    if not data.has_keypoints or frac <= 0 or len(data.cameras) < 3:
        return data, none, none
    flags, best = inconsistent_views(data.rig, data.kp_xy, data.kp_vis, data.kp_size, frac)
    if not flags.any():
        return data, flags, flags
    lm_flags = flags
    if landmark_subset is not None:
        sub = np.asarray(landmark_subset)
        w = (data.vis[..., sub] > lm_min_vis).astype(np.float64)
        E_lm = view_errors(data.rig, data.xy[..., sub, :].astype(np.float64), w, data.kp_size.astype(np.float64))
        lm_flags = flags & (at_pair(E_lm, best) > 0.25 * frac)  # NaN (too few landmarks seen) stays
    kp_keep = (~flags).astype(np.float32)[..., None]
    vis = data.vis * (~lm_flags).astype(np.float32)[..., None]
    hand_vis = None if data.hand_vis is None else data.hand_vis * kp_keep
    return dataclasses.replace(data, vis=vis, kp_vis=data.kp_vis * kp_keep, hand_vis=hand_vis), flags, lm_flags


def set_aside_summary(cameras: list[str], person_ids: list[int], flags: np.ndarray, lm_flags: np.ndarray) -> dict:
    """{camera: {person: {"keypoints": frames, "landmarks": frames}}} of the views set aside."""
    return {c: {str(p): {"keypoints": int(flags[ci, pi].sum()), "landmarks": int(lm_flags[ci, pi].sum())}
                for pi, p in enumerate(person_ids) if flags[ci, pi].any()}
            for ci, c in enumerate(cameras) if flags[ci].any()}


def set_aside_inconsistent(data, frac: float, landmark_subset: np.ndarray | None = None, lm_min_vis: float = 0.2):
    """``data`` with inconsistent views set aside (set_aside_flags) and the summary of what was
    (set_aside_summary; {} when nothing was)."""
    out, flags, lm_flags = set_aside_flags(data, frac, landmark_subset, lm_min_vis)
    if not flags.any():
        return data, {}
    return out, set_aside_summary(data.cameras, data.person_ids, flags, lm_flags)
