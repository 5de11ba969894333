"""Cycle-consistent multi-view grouping of tracks into persons.

Nodes are the tracks of all views. Between two views we have an affinity matrix (tracklet
epipolar affinities). The grouping is a partition of the nodes in which no group holds two
tracks of one view that exist at the same time (two tracks of one view that never co-exist --
a track that broke and restarted -- may share a group). A partition is cycle-consistent by
construction: if a~b and b~c then a and c are in the same group.

1. Per camera pair, a Hungarian assignment (scipy linear_sum_assignment on 1 - A), repeated
   on the left-over tracks so that a track may also take a second partner that never co-exists
   with its first (a person whose track broke in one view).
2. The assignment edges, strongest first, merge groups when (a) the merged group keeps view
   exclusivity and (b) the mean affinity between the two groups over every pair of tracks with
   shared evidence (average linkage) stays above ``min_affinity``. An edge that fails is
   rejected with its reason; one bad pairwise match therefore cannot chain two people together
   as union-find over edges (connected components) would.
3. Groups left apart are merged by the same average linkage when it clears ``min_affinity``
   (rejoins tracks whose pairwise assignment lost to a wrong partner).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment


@dataclass
class Node:
    view: int
    track: int  # track id in its view
    presence: np.ndarray  # (T_view,) bool, frames with landmarks


@dataclass
class Grouping:
    groups: list[list[int]]  # node indices per group
    rejected: list[dict] = field(default_factory=list)
    edges: list[tuple[int, int, float]] = field(default_factory=list)  # accepted assignment edges


def coexist(p: np.ndarray, q: np.ndarray, tolerance: int) -> bool:
    """Two tracks of one view co-exist if they share more than ``tolerance`` frames."""
    return int(np.count_nonzero(p & q)) > tolerance


def pair_assignment(A: np.ndarray, eligible: np.ndarray, disjoint_a: np.ndarray, disjoint_b: np.ndarray,
                    max_rounds: int = 8) -> list[tuple[int, int]]:
    """Hungarian assignment on 1 - A over eligible entries, repeated for tracks that never
    co-exist with the partners already given (disjoint_a (Ka, Ka), disjoint_b (Kb, Kb))."""
    Ka, Kb = A.shape
    chosen: list[tuple[int, int]] = []
    partners_a = [[] for _ in range(Ka)]
    partners_b = [[] for _ in range(Kb)]
    for _ in range(max_rounds):
        ok = eligible.copy()
        for i, j in chosen:
            ok[i, j] = False
        for i in range(Ka):
            for j2 in partners_a[i]:
                ok[i] &= disjoint_b[j2]  # a second partner of i must never co-exist with its first
        for j in range(Kb):
            for i2 in partners_b[j]:
                ok[:, j] &= disjoint_a[i2]
        if not ok.any():
            break
        cost = np.where(ok, 1.0 - A, 1e6)
        r, c = linear_sum_assignment(cost)
        new = [(int(i), int(j)) for i, j in zip(r, c) if ok[i, j]]
        if not new:
            break
        for i, j in new:
            chosen.append((i, j))
            partners_a[i].append(j)
            partners_b[j].append(i)
    return chosen


class _Groups:
    """Groups with view-exclusivity and average-linkage checks."""

    def __init__(self, nodes: list[Node], A: np.ndarray, evidence: np.ndarray, tolerance: int):
        self.nodes, self.A, self.evidence, self.tol = nodes, A, evidence, tolerance
        self.of = list(range(len(nodes)))
        self.members: dict[int, list[int]] = {i: [i] for i in range(len(nodes))}

    def conflict(self, g: int, h: int) -> str | None:
        for x in self.members[g]:
            for y in self.members[h]:
                nx, ny = self.nodes[x], self.nodes[y]
                if nx.view == ny.view and coexist(nx.presence, ny.presence, self.tol):
                    return f"view conflict: tracks {nx.track} and {ny.track} of one view co-exist"
        return None

    def linkage(self, g: int, h: int) -> tuple[float, int]:
        mg, mh = np.array(self.members[g]), np.array(self.members[h])
        ev = self.evidence[np.ix_(mg, mh)]
        if not ev.any():
            return float("nan"), 0
        return float(self.A[np.ix_(mg, mh)][ev].mean()), int(ev.sum())

    def merge(self, g: int, h: int) -> None:
        for x in self.members[h]:
            self.of[x] = g
        self.members[g] += self.members.pop(h)


def group_tracks(nodes: list[Node], A: np.ndarray, evidence: np.ndarray, view_pairs: list[tuple[int, int]],
                 min_affinity: float = 0.3, tolerance: int = 2, describe=None) -> Grouping:
    """Partition the nodes into persons (see module doc).

    A (N, N) symmetric affinities (0 on the diagonal and within a view); evidence (N, N) bool:
    the pair shared enough landmarks to be compared; view_pairs: the (va, vb) pairs to assign.
    ``describe(node)`` names a node in rejection records.
    """
    describe = describe or (lambda i: [nodes[i].view, nodes[i].track])
    N = len(nodes)
    view_of = np.array([n.view for n in nodes], np.int64)
    rejected: list[dict] = []
    edges: list[tuple[int, int, float]] = []
    for va, vb in view_pairs:
        ia, ib = np.flatnonzero(view_of == va), np.flatnonzero(view_of == vb)
        if not len(ia) or not len(ib):
            continue
        Ap = A[np.ix_(ia, ib)]
        ev = evidence[np.ix_(ia, ib)]
        dis_a = np.array([[not coexist(nodes[x].presence, nodes[y].presence, tolerance) for y in ia] for x in ia])
        dis_b = np.array([[not coexist(nodes[x].presence, nodes[y].presence, tolerance) for y in ib] for x in ib])
        chosen = pair_assignment(Ap, ev & (Ap >= min_affinity), dis_a, dis_b)
        taken = np.zeros(Ap.shape, bool)
        for i, j in chosen:
            taken[i, j] = True
            edges.append((int(ia[i]), int(ib[j]), float(Ap[i, j])))
        # plausible pairs the assignment did not choose: say which match beat them
        for i, j in zip(*np.nonzero(ev & (Ap >= min_affinity) & ~taken)):
            rival = [f"{describe(ia[i2])}" for i2, j2 in chosen if j2 == j] + \
                    [f"{describe(ib[j2])}" for i2, j2 in chosen if i2 == i]
            rejected.append({"a": describe(ia[i]), "b": describe(ib[j]), "affinity": round(float(Ap[i, j]), 4),
                             "stage": "pair assignment",
                             "reason": "lost the Hungarian assignment to " + (", ".join(rival) or "a better match")})
    G = _Groups(nodes, A, evidence, tolerance)
    accepted: list[tuple[int, int, float]] = []
    for x, y, a in sorted(edges, key=lambda e: -e[2]):
        g, h = G.of[x], G.of[y]
        if g == h:
            accepted.append((x, y, a))
            continue
        why = G.conflict(g, h)
        if why is None:
            link, _ = G.linkage(g, h)
            if not link >= min_affinity:
                why = f"groups disagree: mean affinity {link:.3f} between them is below {min_affinity}"
        if why is None:
            G.merge(g, h)
            accepted.append((x, y, a))
        else:
            rejected.append({"a": describe(x), "b": describe(y), "affinity": round(a, 4), "stage": "grouping",
                             "reason": why})
    # 3. average-linkage merging of what is left apart
    while True:
        keys = sorted(G.members)
        best = None
        for ii, g in enumerate(keys):
            for h in keys[ii + 1:]:
                link, n_ev = G.linkage(g, h)
                if not link >= min_affinity or (best is not None and link <= best[0]):
                    continue
                if G.conflict(g, h) is None:
                    best = (link, g, h)
        if best is None:
            break
        G.merge(best[1], best[2])
    groups = [sorted(m) for m in G.members.values()]
    return Grouping(groups, rejected, accepted)
