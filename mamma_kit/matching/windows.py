"""Identities over a long take: match per time window, chain the windows, keep the capture's people.

A per-view track is not one person for sure: a tracker can jump from one person to another where
they cross, and a person who leaves a view comes back as a new track. Matching whole tracks ties
a jump's two people together. So the take is cut into windows (``window_s`` on the reference
clock); in each, the tracks present are matched across views as in match.match_views (epipolar
tracklet affinities, cycle-consistent grouping), giving window persons. Window persons are then
chained over time: consecutive windows' persons that share tracks (the same track of the same
view) are the same person, decided by a Hungarian assignment on the frames they share, so a
track that changes person changes chain where the other views say so. A window person that
shares tracks with a chain but lost the assignment (a view whose track the window's grouping
left alone) joins that chain when no view of it clashes.

Chains are the persons. A person of the capture is seen by two or more views at once for at
least ``min_multiview_s`` (a track seen by one camera only has no depth and is no one the fit
can place); with ``people`` = N the N best supported are kept (the frames in which two or more
views see them). Everything else is listed with its reason. Per view, a track whose frames all
fall in one person is assigned whole; one that changes person gets segments (core.identities).

Cost: linear in the take's length (each window is matched on its own frames).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from mamma_kit.core.identities import Identities
from mamma_kit.core.tracks import nearest_frames
from mamma_kit.fitting.checks import Limits
from mamma_kit.matching.pairs import ViewTracks
from mamma_kit.matching.sources import ViewSource, take
from mamma_kit.matching.stature import closest_points, exchange_by_stature, rays_through


MIN_RUN = 3  # frames: a track's change of person shorter than this is undone (refine_frames)
CLEARER = 2.0  # refine_frames: another person fitting a track this many times better than its own takes it


@dataclass
class WindowSettings:
    window_s: float = 2.0
    min_multiview_s: float = 0.5
    max_gap_windows: int = 2  # a chain may resume after this many windows without a shared track
    people: int | None = None
    link_gap_s: float = 8.0  # chains this far apart in time may be one person (leaving all views a while)
    link_speed: float = 2.5  # m/s: ... if the gap between their ends is walkable at this speed
    link_margin_m: float = 0.6
    refine: bool = True  # place each track's switches frame by frame (refine_frames)
    stature: bool = True  # two persons' labels exchanged where their limb lengths say so (matching/stature.py)
    # ... a frame whose other views disagree by more than this (person heights) leaves its person:
    # twice the match's own cut-off, since one frame's keypoints are noisier than a tracklet's
    # (AV16.3 meeting room at 0.12 / 0.2 / 0.3: cam2 followed right 82 / 91 / 91 %, cam3 wrong
    # person 0 / 7.7 / 11.6 %)
    refine_reject: float = 0.2
    # a person of the capture is seen by at least this share of the views that see the best-seen
    # person at once (rounded up): a bystander at the edge of the room, seen by two of four cameras
    # while the capture's people are seen by all four, stands outside the cameras' common view
    min_view_share: float = 0.6


@dataclass
class Chain:
    windows: dict[int, dict[tuple[str, int], int]] = field(default_factory=dict)  # window -> {(cam, track): frames}
    multiview_frames: int = 0

    @property
    def last(self) -> int:
        return max(self.windows)

    def views(self) -> set[str]:
        return {c for m in self.windows.values() for c, _ in m}

    def peak_views(self) -> int:
        """The most views that see the person at once: per window, the views holding it for at
        least half as many frames as its best view there."""
        best = 0
        for m in self.windows.values():
            per_view: dict[str, int] = {}
            for (c, _), n in m.items():
                per_view[c] = per_view.get(c, 0) + n
            top = max(per_view.values(), default=0)
            best = max(best, sum(1 for n in per_view.values() if n >= 0.5 * top > 0))
        return best

    def tracks(self) -> dict[tuple[str, int], set[int]]:
        """Each (camera, track) of the chain and the windows it holds it in."""
        out: dict[tuple[str, int], set[int]] = {}
        for w, m in self.windows.items():
            for k in m:
                out.setdefault(k, set()).add(w)
        return out


def window_persons(ident: Identities, views: list[ViewTracks]) -> list[dict[tuple[str, int], int]]:
    """The window's persons: per person {(camera, track): frames present in the window}."""
    frames = {(v.name, int(t)): int(v.valid_tk[:, k].sum()) for v in views for k, t in enumerate(v.track_ids)}
    out: dict[int, dict] = {}
    for c, m in ident.assignments.items():
        for t, p in m.items():
            out.setdefault(p, {})[(c, int(t))] = frames.get((c, int(t)), 0)
    return [m for _, m in sorted(out.items())]


def multiview_frames(members: dict[tuple[str, int], int]) -> int:
    """Frames in which two or more views see a window person: its second-best view's frames."""
    per_view: dict[str, int] = {}
    for (c, _), n in members.items():
        per_view[c] = per_view.get(c, 0) + n
    counts = sorted(per_view.values(), reverse=True)
    return counts[1] if len(counts) > 1 else 0


def chain_windows(per_window: list[list[dict]], max_gap: int, coexist=lambda *a: True) -> list[Chain]:
    """Chains of window persons sharing tracks (see module doc); ``coexist`` as in compatible."""
    chains: list[Chain] = []
    for w, persons in enumerate(per_window):
        live = [i for i, ch in enumerate(chains) if w - ch.last <= max_gap + 1]
        score = np.zeros((len(live), len(persons)))
        for a, i in enumerate(live):
            last = chains[i].windows[chains[i].last]
            for b, m in enumerate(persons):
                score[a, b] = sum(min(n, last[k]) for k, n in m.items() if k in last)
        taken: dict[int, int] = {}
        if score.size:
            r, c = linear_sum_assignment(-score)
            taken = {int(b): live[int(a)] for a, b in zip(r, c) if score[a, b] > 0}
        # the assigned window persons first: a person who lost the assignment joins a chain below
        # only where the chain's own window person leaves its views free
        for b, i in taken.items():
            now = chains[i].windows.get(w, {})
            chains[i].windows[w] = {**now, **persons[b]}
            # the other chains this window person shares tracks with are the same person, when
            # none of their tracks co-exists in a view with one of this chain's
            for a in range(len(live)):
                j = live[a]
                if j != i and j not in taken.values() and score[a, b] > 0 and chains[j].windows \
                        and compatible(chains[i], chains[j], coexist):
                    for wj, m in chains[j].windows.items():
                        chains[i].windows[wj] = {**chains[i].windows.get(wj, {}), **m}
                    chains[j].windows = {}
        for b, m in enumerate(persons):
            if b in taken:
                continue
            # a window person that shares tracks with one chain only and clashes with none of its views
            sharing = [live[a] for a in range(len(live)) if score[a, b] > 0 and chains[live[a]].windows]
            if len(sharing) == 1:
                ch = chains[sharing[0]]
                now = ch.windows.get(w, {})
                if not ({c for c, _ in now} & {c for c, _ in m}):
                    ch.windows[w] = {**now, **m}
                    continue
            chains.append(Chain({w: dict(m)}))
        chains = [ch for ch in chains if ch.windows]
    for ch in chains:
        ch.multiview_frames = sum(multiview_frames(m) for m in ch.windows.values())
    return chains


def compatible(a: Chain, b: Chain, coexist) -> bool:
    """No view holds a track of ``a`` and another of ``b`` that co-exist in the windows each
    chain holds it (``coexist(track_a, windows_a, track_b, windows_b)``)."""
    ta, tb = a.tracks(), b.tracks()
    return not any(ka[0] == kb[0] and ka != kb and coexist(ka, wa, kb, wb)
                   for ka, wa in ta.items() for kb, wb in tb.items())


def trim_weak_ends(chains: list[Chain]) -> list[Chain]:
    """A chain's first and last windows seen by one view only are split off as chains of their
    own: a lone view's track at a chain's end is where a tracker jumps to someone else, and
    across a gap only the multi-view part says where the person is."""
    out = []
    for ch in chains:
        ws = sorted(ch.windows)
        strong = [w for w in ws if len({c for c, _ in ch.windows[w]}) >= 2]
        if not strong:
            out.append(ch)
            continue
        lo, hi = strong[0], strong[-1]
        out.append(Chain({w: m for w, m in ch.windows.items() if lo <= w <= hi}))
        for part in ([w for w in ws if w < lo], [w for w in ws if w > hi]):
            if part:
                out.append(Chain({w: ch.windows[w] for w in part}))
    for ch in out:
        ch.multiview_frames = sum(multiview_frames(m) for m in ch.windows.values())
    return out


def link_chains(chains: list[Chain], ends, coexist, s: WindowSettings) -> list[Chain]:
    """Chains that follow each other in time where a person could walk from one's end to the
    other's start (``ends(chain)`` -> ((t, X) first, (t, X) last) of its multi-view frames, or
    None), with no view conflict, are one person (nearest pairs first)."""
    while True:
        best = None
        info = [ends(ch) for ch in chains]
        for i, a in enumerate(chains):
            for j, b in enumerate(chains):
                if i == j or info[i] is None or info[j] is None:
                    continue
                (_, _), (t_a, X_a) = info[i]
                (t_b, X_b), _ = info[j]
                gap = t_b - t_a
                if not 0 < gap <= s.link_gap_s or max(a.windows) > min(b.windows):
                    continue
                d = float(np.linalg.norm(X_b - X_a))
                if d > s.link_margin_m + s.link_speed * gap or not compatible(a, b, coexist):
                    continue
                if best is None or d < best[0]:
                    best = (d, i, j)
        if best is None:
            return chains
        _, i, j = best
        for w, m in chains[j].windows.items():
            chains[i].windows[w] = {**chains[i].windows.get(w, {}), **m}
        chains[i].multiview_frames += chains[j].multiview_frames
        del chains[j]


class TrackGeometry:
    """Per (camera, track): its frames' reference times, presence and the centroid of its
    visible points (undistorted px), to tell whether two tracks co-exist and where a chain is."""

    def __init__(self, views: list[ViewSource], edges: np.ndarray):
        self.views = {v.name: v for v in views}
        self.window_of = {v.name: np.searchsorted(edges, v.times_ref, side="right") - 1 for v in views}
        self._positions: dict = {}
        self.col = {(v.name, int(t)): k for v in views for k, t in enumerate(v.track_ids)}
        self.centroid = {v.name: v.centroid_tk2 for v in views}

    def coexist(self, a: tuple[str, int], wins_a, b: tuple[str, int], wins_b, handover_s: float = 1.0) -> bool:
        """Two tracks of one view, each in the given windows, show two people: they share more
        frames there than a tracker's hand-over takes (a new track starting on a person before
        the old one, drifting off, lets go)."""
        v, win = self.views[a[0]], self.window_of[a[0]]
        pa = v.valid_tk[:, self.col[a]] & np.isin(win, list(wins_a))
        pb = v.valid_tk[:, self.col[b]] & np.isin(win, list(wins_b))
        return int(np.count_nonzero(pa & pb)) > max(2, handover_s / v.period)

    def positions(self, ch: Chain) -> tuple[np.ndarray, np.ndarray]:
        """Times (n,) and triangulated centroids (n, 3) of the chain's multi-view frames (kept
        for each state of a chain: linking and selection ask again and again)."""
        key = tuple(sorted((w, tuple(sorted(m))) for w, m in ch.windows.items()))
        if key not in self._positions:
            self._positions[key] = self._positions_of(ch)
        return self._positions[key]

    def _positions_of(self, ch: Chain) -> tuple[np.ndarray, np.ndarray]:
        t_n, X_n3 = [np.zeros(0)], [np.zeros((0, 3))]
        for w in sorted(ch.windows):
            members = list(ch.windows[w])
            if len({c for c, _ in members}) >= 2:
                for t, X in self.triangulated(members, w):
                    t_n.append(t)
                    X_n3.append(X)
        t, X = np.concatenate(t_n), np.concatenate(X_n3)
        order = np.argsort(t, kind="stable")
        return t[order], X[order]

    def same_place(self, a: Chain, b: Chain, radius: float = 0.35, share: float = 0.5) -> bool:
        """Chain a is within ``radius`` of chain b at more than ``share`` of the instants both are
        triangulated and of a's own: two people cannot stand in one place, and a duplicate track
        follows its person for most of its length (a few instants near b, where b's chain took a
        track that jumped to a's person, make a no duplicate)."""
        ta, Xa = self.positions(a)
        tb, Xb = self.positions(b)
        if not len(ta) or not len(tb):
            return False
        j = nearest_frames(ta, tb, tol=0.05)
        both = j >= 0
        if both.sum() < 3:
            return False
        close = np.linalg.norm(Xa[both] - Xb[j[both]], axis=1) < radius
        return float(close.mean()) > share and float(close.sum()) > share * len(ta)

    def ends(self, ch: Chain, n: int = 5):
        """((t, X) of the chain's first multi-view frames, (t, X) of its last), X the median of
        ``n`` frames' triangulated centroids; None without two views at once."""
        t, X = self.positions(ch)
        if not len(t):
            return None
        return (t[0], np.median(X[:n], 0)), (t[-1], np.median(X[-n:], 0))

    def triangulated(self, members, window: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per track of the members' main view (the one with most frames), times (n,) and points
        (n, 3) at its frames in ``window`` where two or more views' tracks are seen: the point
        nearest to their centroids' rays (a window person is those tracks in that window only: a
        track that jumps to someone else later is someone else there)."""
        by_view: dict[str, list] = {}
        for key in members:
            by_view.setdefault(key[0], []).append(key)
        main = max(by_view, key=lambda c: sum((self.views[c].valid_tk[:, self.col[k]] & (self.window_of[c] == window)).sum()
                                              for k in by_view[c]))
        vm = self.views[main]
        out = []
        for key in by_view[main]:
            f = np.flatnonzero(vm.valid_tk[:, self.col[key]] & (self.window_of[main] == window))
            t = vm.times_ref[f]
            rays = [self._rays(main, self.col[key], f)]  # each (F, 3) origin, (F, 3) direction, (F,) ok
            for c, keys in by_view.items():
                if c != main:
                    v = self.views[c]
                    g = nearest_frames(t, v.times_ref, 0.5 * v.period)
                    for kk in keys:
                        o, d, ok = self._rays(c, self.col[kk], np.maximum(g, 0))
                        rays.append((o, d, ok & (g >= 0) & v.valid_tk[np.maximum(g, 0), self.col[kk]]))
            X, n = closest_points(rays)
            out.append((t[n >= 2], X[n >= 2]))
        return out

    def _rays(self, cam: str, k: int, frames: np.ndarray):
        """Rays through track k's centroid at the frames: origins (F, 3), unit directions (F, 3),
        and which exist (F,)."""
        c = self.centroid[cam][frames, k]  # (F, 2)
        return rays_through(self.views[cam].camera, c, np.ones(len(c), bool))


def refuse_impossible(chains: list[Chain], geo: TrackGeometry, limits: Limits = Limits()) -> tuple[list[Chain], list]:
    """The fit's physical checks (fitting.checks.Limits) on the match: where a window person's
    triangulated place lies behind (or at) a camera it takes a track from, or inside it, that
    camera's tracks leave the person in that window. A wrong pairing satisfies the epipolar
    constraint and triangulates somewhere, here where no body can be; the fit would follow it.
    Returns the chains left and what was refused, with the reason."""
    refused = []
    for ch in chains:
        for w in sorted(ch.windows):
            members = ch.windows[w]
            cams = sorted({c for c, _ in members})
            if len(cams) < 2:
                continue
            pts = [X for _, X in geo.triangulated(list(members), w)]
            X = np.concatenate(pts) if pts else np.zeros((0, 3))
            X = X[np.isfinite(X).all(1)]
            if len(X) < MIN_RUN:
                continue
            for c in cams:
                cam = geo.views[c].camera
                depth = cam.to_camera(X)[:, 2]
                near = np.linalg.norm(X - cam.center, axis=1)
                if np.mean(depth < limits.min_depth_m) > 0.5:
                    why = (f"the person they were matched into lies behind {c} (median {np.median(depth):+.2f} m "
                           f"along its view)")
                elif np.mean(near < limits.near_camera_m) > 0.5:
                    why = f"the person they were matched into lies inside {c} ({np.median(near):.2f} m from its centre)"
                else:
                    continue
                gone = sorted(t for cc, t in members if cc == c)
                ch.windows[w] = {k: n for k, n in ch.windows[w].items() if k[0] != c}
                refused.append({"window": int(w), "camera": c, "tracks": gone, "reason": why})
        ch.windows = {w: m for w, m in ch.windows.items() if m}
        ch.multiview_frames = sum(multiview_frames(m) for m in ch.windows.values())
    return [ch for ch in chains if ch.windows], refused


def select_chains(chains: list[Chain], period: float, s: WindowSettings, n_frames: int,
                  same_place=lambda a, b: False) -> tuple[list[Chain], list[dict]]:
    """The capture's persons (best supported first) and why the other chains are not
    (``n_frames``: the take's length in frames; a take under a few seconds asks for a sixth of it;
    ``same_place(a, b)``: chain a is where b is whenever both are seen, a duplicate of b)."""
    ranked = sorted(chains, key=lambda ch: (-ch.multiview_frames, -len(ch.views()), min(ch.windows)))
    need = max(1, min(int(round(s.min_multiview_s / max(period, 1e-6))), max(2, n_frames // 6)))
    kept, dropped = [], []
    peaks = {id(ch): ch.peak_views() for ch in ranked}
    peak = max((peaks[id(ch)] for ch in ranked if ch.multiview_frames >= need), default=0)
    min_views = max(2, int(np.ceil(s.min_view_share * peak - 1e-9)))
    for ch in ranked:
        views = sorted(ch.views())
        why = None
        if len(views) < 2:
            why = f"seen by {views[0] + ' only' if views else 'no camera'}"
        elif ch.multiview_frames < need:
            why = f"seen by two or more cameras at once in {ch.multiview_frames} frames only (< {s.min_multiview_s} s)"
        elif peaks[id(ch)] < min_views:
            why = (f"seen by {peaks[id(ch)]} cameras at once at most, the best-seen person by {peak}: outside the "
                   "cameras' common view (a bystander)")
        elif any(same_place(ch, k) for k in kept):
            pid = next(i for i, k in enumerate(kept) if same_place(ch, k))
            why = f"where person {pid} is whenever both are seen: duplicate tracks of that person"
        elif s.people and len(kept) >= s.people:
            why = f"not one of the {s.people} people best seen (--people {s.people})"
        if why is None:
            kept.append(ch)
        else:
            dropped.append({"views": views, "multiview_frames": ch.multiview_frames, "reason": why,
                            "tracks": sorted({f"{c}:{t}" for m in ch.windows.values() for c, t in m})})
    return kept, dropped


def person_arrays(kept: list[Chain], views: list[ViewTracks], edges: np.ndarray) -> dict[str, np.ndarray]:
    """Per view (T, K) the person id (rank among the kept chains) each track shows at each of
    its frames by the windows' chaining; -1 for none."""
    out = {}
    for v in views:
        win = np.searchsorted(edges, v.times_ref, side="right") - 1
        arr = np.full(v.valid_tk.shape, -1, np.int64)
        col = {int(t): k for k, t in enumerate(v.track_ids)}
        for pid, ch in enumerate(kept):
            for w, m in ch.windows.items():
                for cam, tid in m:
                    if cam == v.name:
                        k = col[tid]
                        arr[(win == w) & v.valid_tk[:, k], k] = pid
        out[v.name] = arr
    return out


def refine_frames(person: dict[str, np.ndarray], views: list[ViewSource], edges: np.ndarray, accept: float,
                  reject: float) -> dict[str, np.ndarray]:
    """Frame by frame, each track against the other views' tracks of each person at that
    instant (median epipolar distance over those views, person heights): a frame whose person
    the other views disagree with (> ``reject``) goes to the person they agree with (< ``accept``)
    if no other track of the view holds that person then, else to no one; an unassigned frame the
    other views agree with joins that person; a track that another person fits CLEARER times
    better than its own (and worse than ``accept`` its own) changes too, the frame's changing
    tracks taking the persons free at that instant by a Hungarian assignment, so two tracks that
    swapped people who stay close are swapped back. The windows' chaining decides who is who; this
    places the switch of a track that jumps within a window on its frame. One window of frames
    is read at a time (the other views a frame beyond it on each side, for the instants they
    share); a change shorter than MIN_RUN frames is then undone over the whole take."""
    P = 1 + max((int(a.max()) for a in person.values() if a.size), default=-1)
    if P == 0:
        return person
    out = {n: a.copy() for n, a in person.items()}
    for w in range(len(edges) - 1):
        lo, hi = edges[w], edges[w + 1]
        wide = {v.name: v.window(lo - 1.5 * v.period, hi + 1.5 * v.period) for v in views}
        index = {v.name: v for v in views}
        for a in views:
            va = wide[a.name]
            if va is None:
                continue
            inside = np.flatnonzero((va.times_ref >= lo) & (va.times_ref < hi))
            if not len(inside):
                continue
            f0 = int(np.searchsorted(a.times_ref, va.times_ref[inside[0]]))
            frames = f0 + np.arange(len(inside))  # the take's frame of each of the window's frames
            cols = np.searchsorted(a.track_ids, va.track_ids) if np.all(np.diff(a.track_ids) > 0) else \
                np.array([int(np.flatnonzero(a.track_ids == t)[0]) for t in va.track_ids])
            others = [(wide[b.name], index[b.name]) for b in views if b is not a and wide[b.name] is not None]
            reassign_frames(take(va, inside), frames, cols, others, person, out[a.name], P, accept, reject)
    for a in views:
        undo_short_changes(person[a.name], out[a.name], a.valid_tk)
    return out


def reassign_frames(va: ViewTracks, frames: np.ndarray, cols: np.ndarray, others: list[tuple[ViewTracks, ViewSource]],
                    person: dict[str, np.ndarray], new_tk: np.ndarray, P: int, accept: float, reject: float) -> None:
    """refine_frames' decision for one view's window ``va`` (its frames and columns in the take:
    ``frames``, ``cols``) against the other views' windows; writes into ``new_tk`` (T, K)."""
    from mamma_kit.matching.pairs import frame_distances

    cur_all = person[va.name]
    per_p = np.full((P, max(1, len(others)), *va.valid_tk.shape), np.nan)  # (P, B, F, Kw)
    for bi, (vb, b) in enumerate(others):
        D = frame_distances(va, vb)  # (F, Ka, Kb)
        g = nearest_frames(va.times_ref, vb.times_ref, 0.5 * vb.period)
        fb = np.searchsorted(b.times_ref, vb.times_ref[0]) + np.maximum(g, 0)  # the take's frames of b
        cb = np.array([int(np.flatnonzero(b.track_ids == t)[0]) for t in vb.track_ids], np.int64)
        pb = np.where((g >= 0)[:, None], person[b.name][fb][:, cb], -1)  # (F, Kb)
        for p in range(P):
            hold = pb == p  # (F, Kb)
            with np.errstate(invalid="ignore"):
                d = np.where(hold[:, None, :], D, np.nan)
                per_p[p, bi] = np.where(hold.any(1)[:, None], np.nanmin(np.nan_to_num(d, nan=np.inf), -1), np.nan)
    per_p[~np.isfinite(per_p)] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        Dp = np.nanmedian(per_p, axis=1)  # (P, F, Kw)
    cur = cur_all[frames][:, cols]
    Dinf = np.where(np.isnan(Dp), np.inf, Dp)
    best = np.argmin(Dinf, axis=0)  # (F, Kw)
    best_d = np.take_along_axis(Dinf, best[None], 0)[0]
    own_d = np.where(cur >= 0, np.take_along_axis(Dp, np.maximum(cur, 0)[None], 0)[0], np.nan)
    with np.errstate(invalid="ignore"):
        # a track whose person the other views disagree with, one without a person, and one that
        # fits another person far better than its own (two tracks that swapped people where they
        # cross: each is still near its old person, but the other fits at a fraction of it)
        change_tk = (cur < 0) | (own_d > reject) | ((own_d > accept) & (own_d > CLEARER * best_d) & (best != cur))
    change_tk &= va.valid_tk
    for t in np.flatnonzero(change_tk.any(1)):
        T, ks = frames[t], np.flatnonzero(change_tk[t])
        was = new_tk[T, cols[ks]].copy()
        new_tk[T, cols[ks]] = -1
        held = set(int(p) for p in new_tk[T] if p >= 0)  # by the view's tracks that keep their person
        C = Dinf[:, t, ks].T.copy()  # (changing tracks, P)
        C[:, sorted(held)] = np.inf
        C[C >= accept] = np.inf
        got = {}
        if np.isfinite(C).any():
            r, c = linear_sum_assignment(np.where(np.isfinite(C), C, 1e6))
            got = {int(i): int(j) for i, j in zip(r, c) if np.isfinite(C[i, j])}
        for i, k in enumerate(ks):
            if i in got:
                new_tk[T, cols[k]] = got[i]
            elif was[i] >= 0 and not own_d[t, k] > reject and was[i] not in got.values():
                new_tk[T, cols[k]] = was[i]  # it found no clearly better person: it keeps its own


def undo_short_changes(cur_tk: np.ndarray, new_tk: np.ndarray, valid_tk: np.ndarray) -> None:
    """A change of person shorter than MIN_RUN of a track's frames is one frame's noise, not a
    jump: undone in ``new_tk``."""
    for k in range(cur_tk.shape[1]):
        f = np.flatnonzero(valid_tk[:, k])
        changed = new_tk[f, k] != cur_tk[f, k]
        if not changed.any():
            continue
        for run in np.split(np.arange(len(f)), np.flatnonzero(np.diff(new_tk[f, k]) != 0) + 1):
            if changed[run].any() and len(run) < MIN_RUN:
                new_tk[f[run], k] = cur_tk[f[run], k]


def identities_from_person(person: dict[str, np.ndarray], views: list[ViewTracks]) -> \
        tuple[dict[str, dict[int, int]], dict[str, list], dict[tuple[str, int], int]]:
    """assignments, segments and frames per track from per-frame person ids."""
    assignments: dict[str, dict[int, int]] = {v.name: {} for v in views}
    segments: dict[str, list] = {}
    frames: dict[tuple[str, int], int] = {}
    for v in views:
        for k, tid in enumerate(v.track_ids):
            f = np.flatnonzero(v.valid_tk[:, k])
            who = person[v.name][f, k]
            if not (who >= 0).any():
                continue
            tid = int(tid)
            frames[(v.name, tid)] = int((who >= 0).sum())
            ids, counts = np.unique(who[who >= 0], return_counts=True)
            assignments[v.name][tid] = int(ids[np.argmax(counts)])
            if len(ids) == 1 and (who >= 0).all():
                continue
            # runs of one person -> segments from its first to its last frame
            t = v.times_ref[f]
            for run in np.split(np.arange(len(who)), np.flatnonzero(np.diff(who) != 0) + 1):
                if who[run[0]] >= 0:
                    segments.setdefault(v.name, []).append((tid, float(t[run[0]]), float(t[run[-1]]), int(who[run[0]])))
    return assignments, segments, frames


def _distance_at(affinity: float, lam: float) -> float:
    """The distance whose affinity exp(-D / lam) is ``affinity``."""
    return float(-lam * np.log(affinity))


def merge_pairs(window_pairs: list[dict]) -> dict:
    """The windows' pair records ("camA|camB" -> rows, cols, affinity, distance, ...) as one
    record per camera pair over the whole take: shared observations summed, affinity and
    distances averaged with them as weights."""
    acc: dict[str, dict] = {}
    for pairs in window_pairs:
        for key, rec in pairs.items():
            a = acc.setdefault(key, {"cells": {}, "source": {}})
            a["source"][rec["source"]] = a["source"].get(rec["source"], 0) + 1
            for i, ta in enumerate(rec["rows"]):
                for j, tb in enumerate(rec["cols"]):
                    n = rec["shared_landmarks"][i][j]
                    c = a["cells"].setdefault((int(ta), int(tb)), [0, 0, 0.0, 0.0, 0.0])
                    c[0] += n
                    c[1] += rec["shared_frames"][i][j]
                    for slot, name in ((2, "affinity"), (3, "distance"), (4, "distance_px")):
                        v = rec[name][i][j]
                        if v is not None and n:
                            c[slot] += v * n
    out = {}
    for key, a in acc.items():
        rows = sorted({ta for ta, _ in a["cells"]})
        cols = sorted({tb for _, tb in a["cells"]})

        def grid(slot, digits):
            g = []
            for ta in rows:
                row = []
                for tb in cols:
                    c = a["cells"].get((ta, tb))
                    row.append(None if not c or not c[0] else round(c[slot] / c[0], digits))
                g.append(row)
            return g

        out[key] = {"rows": rows, "cols": cols, "affinity": grid(2, 4), "distance": grid(3, 4),
                    "distance_px": grid(4, 2),
                    "shared_landmarks": [[a["cells"].get((ta, tb), [0])[0] for tb in cols] for ta in rows],
                    "shared_frames": [[a["cells"].get((ta, tb), [0, 0])[1] for tb in cols] for ta in rows],
                    "source": max(a["source"], key=a["source"].get)}
    return out


def match_take(views: list[ViewTracks | ViewSource], kp_views: list[ViewTracks | ViewSource | None] | None,
               settings=None, ws: WindowSettings | None = None) -> Identities:
    """Identities of the whole take (see module doc). ``views``: each camera's landmark tracks,
    in memory or as sources read a window at a time (matching.sources); ``kp_views``: its keypoint
    tracks where the same tracks have them."""
    from dataclasses import asdict

    from mamma_kit.matching.match import MatchSettings, match_views

    s = settings or MatchSettings()
    w_s = ws or WindowSettings()
    views = [v if isinstance(v, ViewSource) else ViewSource.in_memory(v) for v in views]
    if kp_views is not None:
        kp_views = [k if k is None or isinstance(k, ViewSource) else ViewSource.in_memory(k) for k in kp_views]
    names = [v.name for v in views]
    t_all = np.concatenate([v.times_ref[v.valid_tk.any(1)] for v in views] + [np.zeros(0)])
    t_lo = float(t_all.min()) if len(t_all) else 0.0
    t_hi = float(t_all.max()) if len(t_all) else 0.0
    n_win = max(1, int(np.ceil((t_hi - t_lo) / w_s.window_s + 1e-9)))
    edges = t_lo + w_s.window_s * np.arange(n_win + 1)
    edges[-1] = np.inf
    per_window, window_pairs, rejected = [], [], []
    for w in range(n_win):
        vs = [v.window(edges[w], edges[w + 1]) for v in views]
        here = [i for i, v in enumerate(vs) if v is not None]
        if len(here) >= 2:
            kw = None
            if kp_views is not None:
                kw = [kp_views[i].window(edges[w], edges[w + 1], vs[i].track_ids) if kp_views[i] is not None else None
                      for i in here]
                kw = [k if k is not None and np.array_equal(k.track_ids, vs[i].track_ids) else None
                      for k, i in zip(kw, here)]
                kw = kw if any(k is not None for k in kw) else None
            ident = match_views([vs[i] for i in here], s, kw)
            per_window.append(window_persons(ident, [vs[i] for i in here]))
            window_pairs.append(ident.pairs)
            rejected += [{**r, "window": w} for r in ident.rejected]
        elif here:
            v = vs[here[0]]
            per_window.append([{(v.name, int(t)): int(v.valid_tk[:, k].sum())} for k, t in enumerate(v.track_ids)])
        else:
            per_window.append([])
    geo = TrackGeometry(views, edges)
    chains = chain_windows(per_window, w_s.max_gap_windows, geo.coexist)
    chains = link_chains(trim_weak_ends(chains), geo.ends, geo.coexist, w_s)
    chains, refused = refuse_impossible(chains, geo)
    period = float(np.median([v.period for v in views]))
    kept, dropped = select_chains(chains, period, w_s, max(len(v.times_ref) for v in views), geo.same_place)
    person = person_arrays(kept, views, edges)
    if w_s.refine:
        dist_views = [k if kp_views is not None and k is not None and np.array_equal(k.track_ids, v.track_ids) else v
                      for v, k in zip(views, kp_views or [None] * len(views))]
        person = refine_frames(person, dist_views, edges, accept=_distance_at(s.min_affinity, s.lam),
                               reject=w_s.refine_reject)
    exchanged = []
    if w_s.stature and kp_views is not None:
        kps = [k for v, k in zip(views, kp_views) if k is not None and np.array_equal(k.track_ids, v.track_ids)]
        person, exchanged = exchange_by_stature(person, views, kps, edges)
    assignments, segments, frames = identities_from_person(person, views)
    assigned = {(c, t) for c, m in assignments.items() for t in m}
    unassigned = [{"camera": v.name, "track": int(t), "reason": "no frame with landmarks"}
                  for v in views for k, t in enumerate(v.track_ids) if not v.valid_tk[:, k].any()]
    reasons = {(r["camera"], t): r["reason"] for r in refused for t in r["tracks"]}
    for d in dropped:
        for key in d["tracks"]:
            c, t = key.rsplit(":", 1)
            reasons.setdefault((c, int(t)), d["reason"])
    unassigned += [{"camera": c, "track": t, "reason": why} for (c, t), why in sorted(reasons.items())
                   if (c, t) not in assigned]
    diag = {
        "persons": len(kept), "windows": n_win, "window_s": w_s.window_s, "people": w_s.people,
        "view_counts": {str(p): len(ch.views()) for p, ch in enumerate(kept)},
        "multiview_frames": {str(p): ch.multiview_frames for p, ch in enumerate(kept)},
        "chains": len(chains), "set_aside": dropped, "refused": refused, "exchanged_by_stature": exchanged,
        "segmented_tracks": sum(len({t for t, *_ in v}) for v in segments.values()),
    }
    settings_d = {**asdict(s), **{k: v for k, v in asdict(w_s).items()}}
    return Identities(names, assignments, merge_pairs(window_pairs), rejected, unassigned, settings_d, diag, {},
                      frames, segments)
