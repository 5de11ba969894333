"""Who is who after two people meet, from their bodies: each person's limb length in 3D.

Two people in the same clothes who cross quickly leave nothing in their paths to tell them apart
(room-wander: two of them swap places in 0.4 s at 2.2 m/s), and where every view's tracker keeps the
wrong one, every view exchanges them at once: the match's 3D consistency holds. Their bodies still
differ, and bone lengths do not change with the pose: a person's limb length L (shoulder to hip to
knee to ankle, the mean of the two sides) from the views' keypoints triangulated is the same while
they walk, squat or turn (room-wander: 1.11 and 1.26 m for the two look-alikes, +-0.02 m per instant).

1. per instant (the frames of the view with most) and person, the keypoints of the tracks each view
   gives that person then, triangulated (the point nearest the rays of two or more views) -> L, and
   the hips' midpoint;
2. each person's own length: the median of their L over the take;
3. for two persons whose lengths differ by MIN_APART or more and by SPREADS times the sum of their
   lengths' spreads over the take (robust standard deviations: where legs are hidden behind a table
   the keypoint model guesses them, and a length that wanders says nothing; the AV16.3 meeting room:
   0.09-0.12 m, room-wander's look-alikes 0.012-0.016 m): instants where, smoothed over
   SMOOTH_FRAMES, each one seen is nearer the other's length than their own by MARGIN of the
   difference (one of them may be seen by no view then, if the one seen is), in runs of MIN_RUN
   instants or more that begin within MEET_M of each other (people exchange identities only where
   they meet): the two persons' labels are exchanged there, in every view.

Persons of similar build (under MIN_APART apart) are left as the match gave them.
"""

from __future__ import annotations

import warnings

import numpy as np

from mamma_kit.core.tracks import nearest_frames

# BlazePose's shoulders, hips, knees and ankles (left, right)
LIMB_CHAIN = np.array([[11, 23, 25, 27], [12, 24, 26, 28]])
MIN_APART = 0.08  # m between two persons' lengths: closer builds are not told apart
SPREADS = 2.0
MARGIN = 0.5  # of that difference: how much nearer the other's length an instant must be
SMOOTH_FRAMES = 5
MIN_RUN = 3  # instants
MEET_M = 1.0


def closest_points(rays) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the point nearest to that row's rays in the least-squares sense, and how many rays
    it had. ``rays``: [(origins (F, 3), unit directions (F, 3), ok (F,))]."""
    F = len(rays[0][0])
    A = np.zeros((F, 3, 3))
    b = np.zeros((F, 3))
    n = np.zeros(F, np.int64)
    for o, d, ok in rays:
        M = (np.eye(3) - d[:, :, None] * d[:, None, :]) * ok[:, None, None]
        A += M
        b += np.einsum("fij,fj->fi", M, o)
        n += ok
    X = np.full((F, 3), np.nan)
    two = n >= 2
    if two.any():
        X[two] = np.linalg.solve(A[two], b[two][..., None])[..., 0]
    return X, n


def rays_through(camera, xy_n2: np.ndarray, ok_n: np.ndarray):
    """Rays through undistorted pixels (N, 2): origins, unit directions (N, 3), which exist (N,)."""
    d = np.linalg.solve(camera.K, np.c_[np.nan_to_num(xy_n2), np.ones(len(xy_n2))].T).T @ camera.R
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(camera.center, d.shape), d, ok_n & np.isfinite(xy_n2).all(-1)


def limb_lengths(person: dict[str, np.ndarray], views: list, edges: np.ndarray, P: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times (N,), L (N, P) m, hips' midpoint (N, P, 3)) per instant of the view with most frames,
    NaN where fewer than two views see the person. ``views``: keypoint ViewSources (33 points),
    ``person``: view name -> (T, K) person per frame and track, read a window of ``edges`` at a time."""
    grid_v = max(views, key=lambda v: len(v.times_ref))
    times = grid_v.times_ref
    joints = np.r_[LIMB_CHAIN[0], LIMB_CHAIN[1]]  # (8,)
    L = np.full((len(times), P), np.nan)
    hips = np.full((len(times), P, 3), np.nan)
    for w in range(len(edges) - 1):
        at = np.flatnonzero((times >= edges[w]) & (times < edges[w + 1]))
        if not len(at):
            continue
        rays: dict[int, list] = {p: [] for p in range(P)}  # per person: per view (o, d, ok) of (n, 8) points
        for v in views:
            vw = v.window(edges[w] - v.period, edges[w + 1] + v.period)
            if vw is None:
                continue
            g = nearest_frames(times[at], vw.times_ref, 0.5 * v.period)
            f0 = int(np.searchsorted(v.times_ref, vw.times_ref[0]))
            cols = np.array([int(np.flatnonzero(v.track_ids == t)[0]) for t in vw.track_ids], np.int64)
            who = np.where((g >= 0)[:, None], person[v.name][f0 + np.maximum(g, 0)][:, cols], -1)  # (n, Kw)
            who = np.where(vw.valid_tk[np.maximum(g, 0)] & (g >= 0)[:, None], who, -1)
            for p in range(P):
                has = who == p
                one = has.sum(1) == 1  # a person twice in one view is that view's confusion: left out
                if not one.any():
                    continue
                k = np.argmax(has, 1)
                fr = np.maximum(g, 0)
                xy = vw.xy_tkl2[fr, k][:, joints]  # (n, 8, 2)
                ok = one[:, None] & vw.vis_tkl[fr, k][:, joints]
                rays[p].append(rays_through(v.camera, xy.reshape(-1, 2), ok.reshape(-1)))
        for p in range(P):
            if len(rays[p]) < 2:
                continue
            X, _ = closest_points(rays[p])
            X = X.reshape(len(at), 2, 4, 3)  # side, (shoulder, hip, knee, ankle)
            bones = np.linalg.norm(np.diff(X, axis=2), axis=-1).sum(-1)  # (n, 2)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                L[at, p] = np.nanmean(bones, 1)
                hips[at, p] = np.nanmean(X[:, :, 1], 1)
    return times, L, hips


def _smooth(L_np: np.ndarray, n: int = SMOOTH_FRAMES) -> np.ndarray:
    """A running median over n instants (NaN where the instant itself has none)."""
    pad = np.pad(L_np, ((n // 2, n // 2), (0, 0)), constant_values=np.nan)
    win = np.lib.stride_tricks.sliding_window_view(pad, n, axis=0)  # (N, P, n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = np.nanmedian(win, -1)
    return np.where(np.isfinite(L_np), out, np.nan)


def exchanges(times: np.ndarray, L_np: np.ndarray, hips_np3: np.ndarray
              ) -> tuple[list[tuple[int, int, float, float]], np.ndarray]:
    """(p, q, t0, t1): runs of instants where persons p and q wear each other's bodies (module doc),
    each pair once; and each person's own length (P,)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        own = np.nanmedian(L_np, 0)  # (P,)
        spread = 1.4826 * np.nanmedian(np.abs(L_np - own), 0)
    S = _smooth(L_np)
    P = L_np.shape[1]
    out = []
    for p in range(P):
        for q in range(p + 1, P):
            apart = abs(own[p] - own[q])
            if not apart >= max(MIN_APART, SPREADS * (spread[p] + spread[q])):
                continue
            need = MARGIN * apart
            with np.errstate(invalid="ignore"):
                p_is_q = np.abs(S[:, p] - own[q]) < np.abs(S[:, p] - own[p]) - need
                q_is_p = np.abs(S[:, q] - own[p]) < np.abs(S[:, q] - own[q]) - need
            seen_p, seen_q = np.isfinite(S[:, p]), np.isfinite(S[:, q])
            swapped = (p_is_q | ~seen_p) & (q_is_p | ~seen_q) & (seen_p | seen_q)
            for a, b in _runs(swapped):
                met = _meeting(hips_np3, p, q, a) if b - a + 1 >= MIN_RUN else None
                if met is not None:  # exchanged from where they met (their lengths blur while they overlap)
                    out.append((p, q, float(times[min(met, a)]), float(times[b])))
    return out, own


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    i = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(i[::2], i[1::2] - 1))


def _meeting(hips_np3: np.ndarray, p: int, q: int, a: int, look: int = 10) -> int | None:
    """The instant, up to ``look`` before ``a`` (or after it), at which persons p and q were nearest
    each other (each at their last place seen up to then), if within MEET_M; else None."""
    best, at = MEET_M, None
    for t in range(max(0, a - look), min(len(hips_np3), a + look)):
        xp, xq = _last(hips_np3[:, p], t), _last(hips_np3[:, q], t)
        if xp is not None and xq is not None and np.linalg.norm(xp - xq) < best:
            best, at = float(np.linalg.norm(xp - xq)), t
    return at


def _last(x_n3: np.ndarray, t: int):
    ok = np.flatnonzero(np.isfinite(x_n3[:t + 1]).all(-1))
    return x_n3[ok[-1]] if len(ok) else None


def exchange_by_stature(person: dict[str, np.ndarray], views: list, kp_views: list, edges: np.ndarray
                        ) -> tuple[dict[str, np.ndarray], list[dict]]:
    """``person`` (view name -> (T, K) person per frame and track of ``views``) with the labels of
    two persons exchanged where their limb lengths show the views exchanged them (module doc); and
    what was exchanged. ``kp_views``: keypoint ViewSources of the views that have keypoints."""
    P = 1 + max((int(a.max()) for a in person.values() if a.size), default=-1)
    if P < 2 or len(kp_views) < 2:
        return person, []
    times, L, hips = limb_lengths(person, kp_views, edges, P)
    found, own = exchanges(times, L, hips)
    if not found:
        return person, []
    out = {n: a.copy() for n, a in person.items()}
    done = []
    for p, q, t0, t1 in found:
        for v in views:
            f = (v.times_ref >= t0 - 0.5 * v.period) & (v.times_ref <= t1 + 0.5 * v.period)
            cur = person[v.name][f]
            new = out[v.name][f]
            new[cur == p], new[cur == q] = q, p
            out[v.name][f] = new
        done.append({"persons": [p, q], "from_s": round(t0, 3), "to_s": round(t1, 3),
                     "lengths_m": [round(float(own[p]), 3), round(float(own[q]), 3)]})
    return out, done
