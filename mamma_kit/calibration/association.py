"""Which board observations of different cameras show the board in the same pose.

Phones are not synchronised and their board videos start at different moments, so frames
of different cameras are never simultaneous. mamma-kit therefore relies on what a person
naturally does with a board and what the printed instructions ask for: hold it still
for about a second at each place. A still board is the same board pose in every camera
that sees it during the hold, whatever the cameras' clocks say:

1. per camera, *still runs*: consecutive sampled frames in which the median corner moves
   less than ``still_px`` (board held still);
2. per camera pair, the clock offset that makes their still runs coincide, found by
   trying the offsets that align any two runs and keeping the one under which the most
   coinciding runs agree on the *same relative camera pose* (a geometric check, so
   repetitive hold patterns cannot fool it); pairwise offsets are made consistent over
   the camera graph by least squares;
3. *events*: runs of different cameras that overlap on the common clock (shrunk by the
   offset uncertainty) are one board pose; per camera, the corners are averaged over
   the run's frames.

With a timing model (``clocks``, e.g. a timing.toml of these very videos or genlocked
cameras), offsets are known; then moving-board frames whose times agree within
``sync_tol_s`` also become events.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from mamma_kit.calibration.board import BoardSpec
from mamma_kit.calibration.detect import Detections
from mamma_kit.calibration.intrinsics import board_pose
from mamma_kit.core.camera import Camera, rodrigues
from mamma_kit.core.clock import ClockModel


@dataclass
class Run:
    camera: str
    frames: np.ndarray  # sampled-frame indices
    t0: float  # camera clock (s)
    t1: float
    xy_n2: np.ndarray  # corners averaged over the run (NaN where missing)
    spread_px: float  # largest corner deviation from the average within the run
    pose: tuple[np.ndarray, np.ndarray] | None = None  # board -> camera (rvec, tvec)
    cut_start: bool = False  # the run starts at the video's first sampled frame
    cut_end: bool = False  # the run ends at the video's last sampled frame


@dataclass
class Event:
    """One board pose, seen by one or more cameras."""

    kind: str  # 'hold' (still board), 'sync' (simultaneous frames), 'view' (single-camera view)
    obs: dict[str, np.ndarray]  # camera -> xy_n2 (NaN where missing)
    t_ref: float  # time on the common clock (nan if unknown)
    frames: dict[str, np.ndarray] = field(default_factory=dict)  # camera -> sampled-frame indices
    duration: float = 0.0

    @property
    def cameras(self) -> list[str]:
        return list(self.obs)


def still_runs(det: Detections, still_px: float = 0.3, min_frames: int = 3, min_s: float = 0.25) -> list[Run]:
    """Runs of consecutive sampled frames in which the board does not move."""
    xy = det.xy_fn2
    F = len(xy)
    if F < 2:
        return []
    seen = np.isfinite(xy[..., 0])
    both = seen[1:] & seen[:-1]
    d = np.linalg.norm(xy[1:] - xy[:-1], axis=-1)
    d = np.where(both, d, np.nan)
    step = np.diff(det.times_f)
    dt_nom = np.median(step) if len(step) else 1.0
    # the board moves all corners together; detection noise moves single corners (more on
    # small, oblique views), so the median corner displacement is the motion
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        d_med = np.nanmedian(d, axis=1)
    still = (both.sum(1) >= 4) & (d_med < still_px) & (step < 2.5 * dt_nom)  # (F-1,) frame k -> k+1
    spans = []
    k = 0
    while k < F - 1:
        if not still[k]:
            k += 1
            continue
        j = k
        while j < F - 1 and still[j]:
            j += 1
        spans.append([k, j])
        k = j
    # a single noisy frame pair must not split one hold in two: merge spans separated by at
    # most two sampled frames whose corners agree
    merged: list[list[int]] = []
    for a, b in spans:
        if merged and a - merged[-1][1] <= 2:
            pa, pb = xy[merged[-1][1]], xy[a]
            m = np.isfinite(pa[:, 0]) & np.isfinite(pb[:, 0])
            if m.sum() >= 4 and np.median(np.linalg.norm(pa[m] - pb[m], axis=1)) < 1.5 * still_px:
                merged[-1][1] = b
                continue
        merged.append([a, b])
    runs = []
    for a, b in merged:
        frames = np.arange(a, b + 1)
        # drop frames whose corners stray from the run's median (slow drift at the ends)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(xy[frames], axis=0)
            dev = np.nanmedian(np.linalg.norm(xy[frames] - med[None], axis=-1), axis=1)
        frames = frames[dev < still_px]
        if len(frames) < min_frames or det.times_f[frames[-1]] - det.times_f[frames[0]] < min_s:
            continue
        sub = xy[frames]
        cnt = np.isfinite(sub[..., 0]).sum(0)
        mean = np.full(sub.shape[1:], np.nan)
        good = cnt >= max(1, 0.5 * len(frames))
        mean[good] = np.nanmean(sub[:, good], axis=0)
        if good.sum() < 4:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            spread = float(np.nanmax(np.linalg.norm(sub - mean[None], axis=-1)))
        runs.append(Run(det.camera, frames, float(det.times_f[frames[0]]), float(det.times_f[frames[-1]]), mean,
                        spread, cut_start=bool(frames[0] <= 1), cut_end=bool(frames[-1] >= F - 2)))
    return runs


def _rel_pose(ra: Run, rb: Run) -> tuple[np.ndarray, np.ndarray]:
    """Camera b -> camera a transform implied by the two runs' board poses."""
    Ra, ta = rodrigues(ra.pose[0]), ra.pose[1]
    Rb, tb = rodrigues(rb.pose[0]), rb.pose[1]
    R = Ra @ Rb.T
    return R, ta - R @ tb


def consistent_poses(rels: list[tuple[np.ndarray, np.ndarray]], ang_tol: float = np.radians(3.0),
                     rel_tol: float = 0.06) -> list[int]:
    """Largest subset of relative poses that agree with one of them (RANSAC-like)."""
    best: list[int] = []
    for i, (Ri, ti) in enumerate(rels):
        members = []
        for j, (Rj, tj) in enumerate(rels):
            c = np.clip((np.trace(Ri.T @ Rj) - 1) / 2, -1, 1)
            if np.arccos(c) < ang_tol and np.linalg.norm(ti - tj) < rel_tol * max(np.linalg.norm(ti), 0.3):
                members.append(j)
        if len(members) > len(best):
            best = members
    return best


def pair_offset(runs_a: list[Run], runs_b: list[Run], max_offset_s: float | None = None
                ) -> tuple[float, int, list[tuple[int, int]]] | None:
    """Clock offset o_b - o_a (t_ref = t_cam + o) under which still runs of a and b coincide
    and agree on the relative camera pose. -> (offset, n agreeing runs, matched run pairs)."""
    A = [r for r in runs_a if r.pose is not None]
    B = [r for r in runs_b if r.pose is not None]
    if not A or not B:
        return None
    ma = np.array([(r.t0 + r.t1) / 2 for r in A])
    mb = np.array([(r.t0 + r.t1) / 2 for r in B])
    cands = (ma[:, None] - mb[None, :]).ravel()
    if max_offset_s is not None:
        cands = cands[np.abs(cands) <= max_offset_s]
    # candidates within 50 ms of one another are the same hypothesis
    cands = np.unique(np.round(cands / 0.05) * 0.05)
    a0 = np.array([r.t0 for r in A])
    a1 = np.array([r.t1 for r in A])
    b0 = np.array([r.t0 for r in B])
    b1 = np.array([r.t1 for r in B])
    best = None
    for d in cands:
        # overlap of a's runs with b's runs shifted onto a's clock
        ov = np.minimum(a1[:, None], b1[None] + d) - np.maximum(a0[:, None], b0[None] + d)
        short = np.minimum((a1 - a0)[:, None], (b1 - b0)[None])
        ia, ib = np.nonzero(ov > 0.5 * np.maximum(short, 1e-6))
        if len(ia) < 2 or (best is not None and len(ia) <= best[1]):
            continue
        # one run of a per run of b: keep the largest overlaps
        order = np.argsort(-ov[ia, ib])
        used_a, used_b, pa, pb = set(), set(), [], []
        for k in order:
            if ia[k] not in used_a and ib[k] not in used_b:
                used_a.add(ia[k])
                used_b.add(ib[k])
                pa.append(ia[k])
                pb.append(ib[k])
        if len(pa) < 2 or (best is not None and len(pa) <= best[1]):
            continue
        rels = [_rel_pose(A[i], B[j]) for i, j in zip(pa, pb)]
        members = consistent_poses(rels)
        if best is None or len(members) > best[1]:
            best = (d, len(members), [(pa[m], pb[m]) for m in members])
    if best is None or best[1] < 2:
        return None
    d, n, pairs = best
    # refine: median over the agreeing runs of the start and end differences, leaving out
    # ends cut by the start or end of a video
    diffs = []
    for i, j in pairs:
        ra, rb = A[i], B[j]
        if not (ra.cut_start or rb.cut_start):
            diffs.append(ra.t0 - rb.t0)
        if not (ra.cut_end or rb.cut_end):
            diffs.append(ra.t1 - rb.t1)
    if diffs:
        d = float(np.median(diffs))
    ida = {id(r): k for k, r in enumerate(runs_a)}
    idb = {id(r): k for k, r in enumerate(runs_b)}
    return d, n, [(ida[id(A[i])], idb[id(B[j])]) for i, j in pairs]


def solve_offsets(names: list[str], pairs: dict[tuple[str, str], tuple[float, int]], reference: str
                  ) -> tuple[dict[str, float], dict[tuple[str, str], float]]:
    """Offsets o_c (t_ref = t_cam + o_c, o_reference = 0) from pairwise o_b - o_a by weighted
    least squares over each connected component holding the reference; pairs that disagree
    with the solution by more than 0.25 s are dropped. -> (offsets, residual per pair)."""
    comp = _component(names, [p for p in pairs], reference)
    idx = {n: k for k, n in enumerate(sorted(comp, key=names.index))}
    use = {p: v for p, v in pairs.items() if p[0] in idx and p[1] in idx}
    for _ in range(3):
        rows, rhs, w = [], [], []
        for (a, b), (d, n) in use.items():
            r = np.zeros(len(idx))
            r[idx[b]] += 1
            r[idx[a]] -= 1
            rows.append(r)
            rhs.append(d)
            w.append(np.sqrt(n))
        r = np.zeros(len(idx))
        r[idx[reference]] = 1
        rows.append(r)
        rhs.append(0.0)
        w.append(100.0)
        A = np.array(rows) * np.array(w)[:, None]
        o, *_ = np.linalg.lstsq(A, np.array(rhs) * np.array(w), rcond=None)
        resid = {p: float(o[idx[p[1]]] - o[idx[p[0]]] - v[0]) for p, v in use.items()}
        bad = [p for p, e in resid.items() if abs(e) > 0.25]
        if not bad:
            break
        for p in bad:
            use.pop(p)
        comp2 = _component(list(idx), list(use), reference)
        idx = {n: k for k, n in enumerate(sorted(comp2, key=names.index))}
        use = {p: v for p, v in use.items() if p[0] in idx and p[1] in idx}
    return {n: float(o[k]) for n, k in idx.items()}, resid


def _component(names: list[str], edges: list[tuple[str, str]], start: str) -> set[str]:
    adj: dict[str, set[str]] = {n: set() for n in names}
    for a, b in edges:
        if a in adj and b in adj:
            adj[a].add(b)
            adj[b].add(a)
    seen, todo = {start}, [start]
    while todo:
        n = todo.pop()
        for m in adj[n] - seen:
            seen.add(m)
            todo.append(m)
    return seen


def components(names: list[str], edges: list[tuple[str, str]]) -> list[list[str]]:
    left = list(names)
    out = []
    while left:
        c = _component(names, edges, left[0])
        out.append([n for n in names if n in c])
        left = [n for n in left if n not in c]
    return out


def build_events(dets: dict[str, Detections], runs: dict[str, list[Run]], offsets: dict[str, float],
                 clocks: dict[str, ClockModel] | None, margin_s: float) -> list[Event]:
    """Group still runs of all cameras into events on the common clock."""
    items = []
    for cam, rs in runs.items():
        if clocks is None and cam not in offsets:
            # a camera with unknown offset: its runs are single-camera events
            for r in rs:
                items.append((np.nan, np.nan, cam, r))
            continue
        for r in rs:
            if clocks is not None:
                a, b = clocks[cam].to_ref(np.array([r.t0, r.t1]))
            else:
                a, b = r.t0 + offsets[cam], r.t1 + offsets[cam]
            items.append((a + margin_s, b - margin_s, cam, r))
    timed = sorted([it for it in items if np.isfinite(it[0]) and it[1] > it[0]], key=lambda it: it[0])
    events: list[Event] = []
    group: list = []
    end = -np.inf
    for it in timed + [None]:
        if it is None or it[0] >= end:
            if group:
                events += _events_from_group(group)
            group = [] if it is None else [it]
            end = -np.inf if it is None else it[1]
        else:
            group.append(it)
            end = max(end, it[1])
    # runs too short for the margin, or of cameras with unknown offset: single-camera holds
    for it in items:
        if not (np.isfinite(it[0]) and it[1] > it[0]):
            r = it[3]
            events.append(Event("hold", {r.camera: r.xy_n2}, np.nan, {r.camera: r.frames}, r.t1 - r.t0))
    return events


def _events_from_group(group: list, merge_px: float = 2.0) -> list[Event]:
    by_cam: dict[str, list] = {}
    for it in group:
        by_cam.setdefault(it[2], []).append(it)
    merged = []
    for cam, its in by_cam.items():
        if len(its) == 1:
            merged.append(its[0])
            continue
        # one hold split in several runs (e.g. by a video key frame) has the same corners;
        # anything else means the board moved and the group is ambiguous
        xys = np.stack([it[3].xy_n2 for it in its])
        ref = xys[0]
        dev = np.nanmax(np.linalg.norm(xys - ref[None], axis=-1))
        if not dev < merge_px:
            return [Event("hold", {it[2]: it[3].xy_n2}, 0.5 * (it[0] + it[1]), {it[2]: it[3].frames},
                          it[3].t1 - it[3].t0) for it in group]
        w = np.array([len(it[3].frames) for it in its], float)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            xy = np.nansum(xys * w[:, None, None], 0) / np.sum(np.isfinite(xys[..., :1]) * w[:, None, None], 0)
        r = Run(cam, np.concatenate([it[3].frames for it in its]), min(it[3].t0 for it in its),
                max(it[3].t1 for it in its), xy, max(it[3].spread_px for it in its))
        merged.append((min(it[0] for it in its), max(it[1] for it in its), cam, r))
    t0 = max(it[0] for it in merged)
    t1 = min(it[1] for it in merged)
    return [Event("hold", {it[2]: it[3].xy_n2 for it in merged}, 0.5 * (t0 + t1),
                  {it[2]: it[3].frames for it in merged}, max(0.0, t1 - t0))]


def sync_events(dets: dict[str, Detections], clocks: dict[str, ClockModel], used: dict[str, set[int]],
                tol_s: float, min_corners: int = 6) -> list[Event]:
    """Moving-board frames of different cameras taken within ``tol_s`` of each other."""
    items = []
    for cam, d in dets.items():
        t = clocks[cam].to_ref(d.times_f)
        ok = d.n_corners_f >= min_corners
        for f in np.nonzero(ok)[0]:
            if int(f) not in used.get(cam, set()):
                items.append((float(t[f]), cam, int(f)))
    items.sort()
    events = []
    k = 0
    while k < len(items):
        j = k + 1
        while j < len(items) and items[j][0] - items[k][0] <= tol_s:
            j += 1
        grp = items[k:j]
        cams = {}
        for t, cam, f in grp:
            cams.setdefault(cam, (t, f))
        if len(cams) >= 2:
            events.append(Event("sync", {c: dets[c].xy_fn2[f] for c, (t, f) in cams.items()},
                                float(np.mean([t for t, _ in cams.values()])),
                                {c: np.array([f]) for c, (t, f) in cams.items()}))
        k = j
    return events


def pose_runs(runs: list[Run], cam: Camera, spec: BoardSpec) -> None:
    for r in runs:
        p = board_pose(cam, spec, r.xy_n2)
        r.pose = None if p is None else (p[0], p[1])
