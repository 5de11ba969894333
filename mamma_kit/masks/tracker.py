"""The builtin backend's identities: ``Track`` (one person's last mask, velocity and colour) and
``Tracker``, which turns each frame's foreground into masks per track id (masks/builtin.py's
docstring, step 3, says how).

A frame's result is a ``Frame``: track id -> (mask (H, W) bool at the working resolution, score).
Its insertion order is part of the behaviour (the first track a fragment sits on takes it), so
the steps below keep the order in which they add tracks.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from mamma_kit.masks.builtin_settings import BuiltinSettings
from mamma_kit.masks.segment import bhattacharyya, components, histogram, split_component, split_side_by_side

Frame = dict[int, tuple[np.ndarray, float]]  # track id -> (mask (H, W) bool, score)
NO_MATCH = 1e6  # re-identification cost of a pair that may not match


@dataclass
class Track:
    tid: int
    mask: np.ndarray  # last observed mask (bool, working resolution)
    centroid: np.ndarray  # (2,) x, y
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    hist: np.ndarray | None = None
    last_seen: int = 0
    area: float = 0.0

    def predicted(self, frame: int) -> np.ndarray:
        """The last mask shifted by the velocity over the frames since it was seen."""
        d = self.velocity * (frame - self.last_seen)
        if not np.any(np.abs(d) >= 0.5):
            return self.mask
        h, w = self.mask.shape
        M = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
        return cv2.warpAffine(self.mask.astype(np.uint8), M, (w, h), flags=cv2.INTER_NEAREST) > 0


# ---- mask geometry -----------------------------------------------------------------------
def centroid(mask: np.ndarray) -> np.ndarray:
    """(2,) x, y mean of the mask's pixels (zeros for an empty mask)."""
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean(), ys.mean()]) if len(xs) else np.zeros(2)


def box(mask: np.ndarray) -> tuple[int, int, int, int]:
    """x0, y0, x1, y1 (exclusive) of a non-empty mask."""
    ys, xs = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
    return xs[0], ys[0], xs[-1] + 1, ys[-1] + 1


def stacked(c: np.ndarray, m: np.ndarray, h: int) -> bool:
    """c lies just above or below m, overlapping it horizontally, and together they are taller
    than wide (one person in two pieces, not two people side by side)."""
    if not m.any():
        return False
    a, b = box(c), box(m)
    overlap_x = min(a[2], b[2]) - max(a[0], b[0])
    gap_y = max(a[1], b[1]) - min(a[3], b[3])
    width = max(a[2], b[2]) - min(a[0], b[0])
    height = max(a[3], b[3]) - min(a[1], b[1])
    return overlap_x >= 0.5 * min(a[2] - a[0], b[2] - b[0]) and gap_y <= 0.04 * h and height >= 1.2 * width


def at_border(c: np.ndarray) -> bool:
    return bool(c[0].any() or c[-1].any() or c[:, 0].any() or c[:, -1].any())


def second_person(c: np.ndarray, main: np.ndarray, h: int) -> bool:
    """A piece c of a track's mask is another person beside the main piece: not a limb (half as
    tall, or a third of the area and upright: someone further away), side by side with it, and
    not stacked above or below it (one person cut in two by clothes the background's colour)."""
    mx0, my0, mx1, my1 = box(main)
    x0, y0, x1, y1 = box(c)
    person_like = (y1 - y0 >= 0.5 * (my1 - my0)
                   or (c.sum() >= 0.3 * main.sum() and y1 - y0 >= 1.2 * (x1 - x0)))
    apart = min(x1, mx1) - max(x0, mx0) <= 0.5 * min(x1 - x0, mx1 - mx0)
    return person_like and apart and not stacked(c, main, h)


def crumbs_of(piece: np.ndarray, mask: np.ndarray, min_area: float) -> np.ndarray:
    """The specks of ``mask`` (parts under ``min_area``) nearer ``piece`` than the rest of it:
    they leave with the piece, or they would still tie the two people together."""
    n, lab = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    small = np.bincount(lab.ravel(), minlength=n) < min_area
    small[0] = False
    crumbs = small[lab] & ~piece
    rest = mask & ~piece & ~crumbs
    if not crumbs.any() or not rest.any():
        return crumbs
    d_piece = cv2.distanceTransform((~piece).astype(np.uint8), cv2.DIST_L2, 3)
    d_rest = cv2.distanceTransform((~rest).astype(np.uint8), cv2.DIST_L2, 3)
    return crumbs & (d_piece < d_rest)


# ---- who claims which component --------------------------------------------------------------
def claim_matrix(comps: list[np.ndarray], preds: list[np.ndarray], pred_areas: list[float]) -> np.ndarray:
    """(C, K) share of each of K predictions that lies in each of C components."""
    claim = np.zeros((len(comps), len(preds)))
    for ci, c in enumerate(comps):
        for j, (p, area) in enumerate(zip(preds, pred_areas)):
            claim[ci, j] = np.count_nonzero(c & p) / area
    return claim


def claimants(claim: np.ndarray, recent: list[int], claim_frac: float) -> list[list[int]]:
    """Per component, the track ids (of ``recent``, the columns of ``claim``) that claim it."""
    whos = []
    for ci in range(len(claim)):
        who = [recent[j] for j in np.flatnonzero(claim[ci] >= claim_frac)]
        if not who and len(recent) and claim[ci].max() > 0:
            # a small overlap still belongs to the best track if no other component holds it better
            j = int(np.argmax(claim[ci]))
            if claim[:, j].argmax() == ci and claim[ci, j] > 0.02:
                who = [recent[j]]
        whos.append(who)
    return whos


def leave_ghosts(comps: list[np.ndarray], whos: list[list[int]], claim: np.ndarray, recent: list[int],
                 preds: dict[int, np.ndarray], h: int) -> None:
    """A track that alone claims a component (its person, seen whole) does not also take a share
    of a component other people claim, unless the share lies above or below its own component
    (one person in two pieces): that share is where the person was while hidden behind
    another, a ghost the prediction would otherwise carry forward. Edits ``whos`` in place."""
    col = {k: j for j, k in enumerate(recent)}
    home: dict[int, list[int]] = {}
    for ci, who in enumerate(whos):
        if len(who) == 1:
            home.setdefault(who[0], []).append(ci)
    for ci, who in enumerate(whos):
        if len(who) < 2:
            continue
        keep = []
        for k in who:
            j = col[k]
            mine = [m for m in home.get(k, []) if claim[m, j] >= claim[ci, j]]
            if mine and not any(stacked(comps[ci] & preds[k], comps[m], h) for m in mine):
                continue  # a ghost
            keep.append(k)
        whos[ci] = keep


def join_fragments(pieces: list[np.ndarray], out: Frame, h: int) -> list[np.ndarray]:
    """Fragments of a person already found this frame (clothes the colour of the background cut
    people in two): stacked above or below a track's mask -> part of it, not a new person.
    Edits ``out``; returns the pieces that are no track's."""
    rest = []
    for c in sorted(pieces, key=lambda c: -int(c.sum())):
        k = next((k for k, (m, _) in out.items() if stacked(c, m, h)), None)
        if k is None:
            rest.append(c)
        else:
            out[k] = (out[k][0] | c, out[k][1])
    return rest


def reid_costs(pieces: list[np.ndarray], lost: list[Track], t: int, cidx: np.ndarray,
               s: BuiltinSettings) -> np.ndarray:
    """(P, L) cost of giving each unclaimed piece to each lost track: colour dissimilarity plus a
    little distance from where the track would be by now; NO_MATCH beyond its reach or when the
    colours differ too much."""
    C = np.full((len(pieces), len(lost)), NO_MATCH)
    for i, c in enumerate(pieces):
        hc = histogram(cidx, c)
        cc = centroid(c)
        for j, tr in enumerate(lost):
            sim = bhattacharyya(hc, tr.hist) if tr.hist is not None else 0.0
            gap = t - tr.last_seen
            reach = np.sqrt(tr.area) * (1.0 + 0.5 * gap) + np.linalg.norm(tr.velocity) * gap
            dist = np.linalg.norm(cc - (tr.centroid + tr.velocity * gap))
            if sim >= s.reid_similarity and dist <= reach:
                C[i, j] = (1 - sim) + 0.2 * dist / max(reach, 1.0)
    return C


# ---- the tracker -------------------------------------------------------------------------------
class Tracker:
    """Frame-by-frame tracker over foreground components (see masks/builtin.py's docstring)."""

    def __init__(self, shape_hw: tuple[int, int], s: BuiltinSettings):
        self.s = s
        self.h, self.w = shape_hw
        self.tracks: dict[int, Track] = {}
        self.next_id = 0
        self.area_px = self.h * self.w

    def step(self, t: int, fg: np.ndarray, cidx: np.ndarray) -> Frame:
        """Masks per track id for frame ``t`` from its foreground (H, W) bool and colour bins (H, W)."""
        s = self.s
        self.next_id_at_frame_start = self.next_id
        comps = components(fg, max(4, int(s.min_area_frac * self.area_px)), int(round(s.link_frac * self.h)))
        self.tracks = {k: tr for k, tr in self.tracks.items() if t - tr.last_seen <= s.max_lost}
        recent = [k for k, tr in self.tracks.items() if t - tr.last_seen <= 2]  # followed by prediction
        preds = {k: self.tracks[k].predicted(t) for k in recent}
        out, pure, unclaimed = self._assign(comps, recent, preds, cidx)
        unclaimed += self._part_company(out, preds, pure)
        unclaimed = join_fragments(unclaimed, out, self.h)
        # re-identify lost tracks, else start new ones
        lost = [k for k, tr in self.tracks.items() if k not in out and t - tr.last_seen > 0]
        # someone entering through the image border shows a hand first: smaller pieces count there
        big = [c for c in unclaimed
               if c.sum() >= s.new_track_area_frac * self.area_px * (s.border_area_factor if at_border(c) else 1.0)]
        if big and lost:
            big = self._reidentify(t, big, lost, out, pure, cidx)
        self._start_tracks(t, big, out, pure, cidx)
        if s.people and len(out) < s.people:
            self._split_blobs(t, out, pure, cidx)
        self._update(t, out, pure, cidx)
        return out

    def _assign(self, comps: list[np.ndarray], recent: list[int], preds: dict[int, np.ndarray],
                cidx: np.ndarray) -> tuple[Frame, set[int], list[np.ndarray]]:
        """Components to the tracks whose predictions claim them: whole to a lone claimant (its id
        goes into ``pure``: seen whole), split between several. Returns (out, pure, unclaimed)."""
        s = self.s
        pred_area = {k: max(float(preds[k].sum()), 1.0) for k in recent}
        claim = claim_matrix(comps, [preds[k] for k in recent], [pred_area[k] for k in recent])
        whos = claimants(claim, recent, s.claim_frac)
        leave_ghosts(comps, whos, claim, recent, preds, self.h)
        out: Frame = {}
        pure: set[int] = set()
        unclaimed = []
        for c, who in zip(comps, whos):
            if not who:
                unclaimed.append(c)
            elif len(who) == 1:
                k = who[0]
                prev = out.get(k)
                out[k] = ((prev[0] | c) if prev else c, 1.0)
                pure.add(k)
            else:
                parts, conf = split_component(c, [preds[k] for k in who], [self.tracks[k].hist for k in who], cidx,
                                              s.colour_weight, s.colour_smooth_frac * self.h, s.axis_weight,
                                              s.axis_separation)
                for k, m, sc in zip(who, parts, conf):
                    if m.sum() < s.occluded_frac * pred_area[k]:
                        continue  # occluded: coasts on its prediction
                    prev = out.get(k)
                    out[k] = ((prev[0] | m) if prev else m, sc)
        return out, pure, unclaimed

    def _reidentify(self, t: int, big: list[np.ndarray], lost: list[int], out: Frame, pure: set[int],
                    cidx: np.ndarray) -> list[np.ndarray]:
        """Unclaimed pieces to recently lost tracks (Hungarian on ``reid_costs``); returns the rest."""
        C = reid_costs(big, [self.tracks[k] for k in lost], t, cidx, self.s)
        r, c_ = linear_sum_assignment(C)
        taken = set()
        for i, j in zip(r, c_):
            if C[i, j] < NO_MATCH:
                out[lost[j]] = (big[i], 1.0)
                pure.add(lost[j])
                taken.add(i)
        return [c for i, c in enumerate(big) if i not in taken]

    def _new_track(self, t: int, m: np.ndarray, cidx: np.ndarray) -> int:
        k = self.next_id
        self.next_id += 1
        self.tracks[k] = Track(k, m, centroid(m), last_seen=t, hist=histogram(cidx, m), area=float(m.sum()))
        return k

    def _start_tracks(self, t: int, pieces: list[np.ndarray], out: Frame, pure: set[int], cidx: np.ndarray) -> None:
        """Each piece starts a track, unless it is a second piece of a person who appeared this frame."""
        for c in pieces:
            k_new = next((k for k in out if k >= self.next_id_at_frame_start and stacked(c, out[k][0], self.h)),
                         None)
            if k_new is not None:
                out[k_new] = (out[k_new][0] | c, 1.0)
                continue
            k = self._new_track(t, c, cidx)
            out[k] = (c, 1.0)
            pure.add(k)

    def _update(self, t: int, out: Frame, pure: set[int], cidx: np.ndarray) -> None:
        """Every track found this frame takes its new mask, centroid and area; a track seen whole
        (``pure``) also updates its velocity and colour histogram."""
        a = self.s.velocity_smoothing
        for k, (m, _) in out.items():
            tr = self.tracks[k]
            c = centroid(m)
            if t > tr.last_seen and tr.area > 0:
                v = (c - tr.centroid) / (t - tr.last_seen)
                if k in pure:  # a split part's centroid is biased: keep the old velocity
                    tr.velocity = a * tr.velocity + (1 - a) * v
            tr.centroid, tr.mask, tr.last_seen, tr.area = c, m, t, float(m.sum())
            if k in pure:
                hc = histogram(cidx, m)
                tr.hist = hc if tr.hist is None else 0.8 * tr.hist + 0.2 * hc

    def _part_company(self, out: Frame, preds: dict[int, np.ndarray], pure: set[int]) -> list[np.ndarray]:
        """A track whose mask holds two person-like pieces side by side followed two people who
        walked in together, touched when it started, or passed close (a few pixels apart they form
        one linked component): the piece its prediction covers best keeps the track; the others are
        returned as unclaimed (re-identified or new tracks). A person broken up by clothes the colour
        of the background breaks into pieces above one another (``stacked``) or into a small piece
        (an arm): those stay. With a head count, it is not exceeded."""
        s = self.s
        freed = []
        big = s.new_track_area_frac * self.area_px
        n_people = sum(1 for m, _ in out.values() if m.sum() >= big)  # slivers do not count as people
        for k in list(out):
            if k not in out:  # merged away
                continue
            m_k = out[k][0]
            if k not in pure or m_k.sum() < 2 * big:  # not a part split off a shared component
                continue
            lst = components(m_k, max(1, int(big)))
            if len(lst) < 2:
                continue
            p = preds.get(k)
            lst.sort(key=lambda c: -(np.count_nonzero(c & p) if p is not None else int(c.sum())))
            main = lst[0]
            for c in lst[1:]:
                if not second_person(c, main, self.h):
                    continue
                room = not s.people or n_people + len(freed) < s.people
                if not room and self._merge_stacked(out, pure, big, keep=k):
                    n_people, room = n_people - 1, True
                if room:
                    c = c | crumbs_of(c, out[k][0], big)
                    freed.append(c)
                    out[k] = (out[k][0] & ~c, out[k][1])
        return freed

    def _merge_stacked(self, out: Frame, pure: set[int], big: float, keep: int) -> bool:
        """Two tracks this frame whose masks lie one above the other like one person's top and
        bottom (a shirt and trousers of different colours followed as two people after an
        occlusion) become one: the head count needs the place for two people seen side by side.
        The larger keeps its id; ``keep`` is not merged away. True if a pair was merged."""
        ks = [k for k in out if out[k][0].sum() >= big and k != keep]
        best = None
        for i, a in enumerate(ks):
            for b in ks[i + 1:]:
                ma, mb = out[a][0], out[b][0]
                if stacked(ma, mb, self.h) and (best is None or ma.sum() + mb.sum() > best[2]):
                    best = (a, b, int(ma.sum() + mb.sum()))
        if best is None:
            return False
        a, b, _ = best
        if out[a][0].sum() < out[b][0].sum():
            a, b = b, a
        out[a] = (out[a][0] | out[b][0], min(out[a][1], out[b][1]))
        del out[b]
        self.tracks.pop(b, None)
        pure.discard(b)
        return True

    def _split_blobs(self, t: int, out: Frame, pure: set[int], cidx: np.ndarray) -> None:
        """Fewer tracks than the people the user said are there: a blob holding two people side
        by side (they came in together, or touch from the first frame) becomes two tracks; from
        then on the usual prediction + colour split keeps them apart."""
        for k in sorted(out, key=lambda k: -int(out[k][0].sum())):
            if len(out) >= self.s.people:
                return
            two = split_side_by_side(out[k][0])
            if two is None:
                continue
            tr = self.tracks[k]
            keep = 0 if np.count_nonzero(two[0] & tr.mask) >= np.count_nonzero(two[1] & tr.mask) else 1
            out[k] = (two[keep], 0.5)
            j = self._new_track(t, two[1 - keep], cidx)
            out[j] = (two[1 - keep], 0.5)
            pure.add(j)
            tr.hist = histogram(cidx, two[keep])
            tr.area = float(two[keep].sum())


# ---- a split carried back in time -----------------------------------------------------------
def parted_from(k_new: int, out: Frame, prev: Frame, share: float = 0.5) -> int | None:
    """The track of the previous frame whose mask held at least ``share`` of new track ``k_new``'s
    mask and which goes on in this frame (``out``): the one it parted from, else None."""
    m = out[k_new][0]
    area = max(int(m.sum()), 1)
    best = max(((np.count_nonzero(pm & m), k) for k, (pm, _) in prev.items() if k in out and k != k_new),
               default=(0, None))
    return best[1] if best[0] >= share * area else None


def split_back(seeds: dict[int, np.ndarray], cidx: np.ndarray, earlier: Iterable[tuple[int, np.ndarray, np.ndarray]],
               s: BuiltinSettings) -> dict[int, Frame]:
    """Frames before two tracks parted, tracked again from the parting backwards in time.

    seeds: track id -> its mask (H, W) in the frame where they parted (with that frame's colour
    bins ``cidx``); earlier: (frame, foreground, colour bins) of the frames before it, newest first.
    A fresh tracker follows only the seeds (anyone else it meets gets ids it ignores), so the blob
    the seeds shared is split between them as for people touching. Returns frame -> the seeds'
    masks, for the frames where every seed keeps a piece, stopping at the first where one does not
    (one of them came in there)."""
    tr = Tracker(cidx.shape, s)
    for k, m in seeds.items():
        tr.tracks[k] = Track(k, m, centroid(m), last_seen=0, hist=histogram(cidx, m), area=float(m.sum()))
    tr.next_id = max(seeds) + (1 << 30)  # others' ids, never the forward tracker's
    res: dict[int, Frame] = {}
    for i, (t, fg, ci) in enumerate(earlier, start=1):
        out = tr.step(i, fg, ci)
        if not all(k in out and out[k][0].any() for k in seeds):
            break
        res[t] = {k: out[k] for k in seeds}
    return res
