"""Stage 4: contact between people, on the CPU.

Signed distance of a point to the other person's posed low-resolution proxy (closed mesh,
about 4k triangles, body.proxy), evaluated only where the two bodies are close:

- gating: frames whose two bodies' 3D boxes (from the posed proxies) intersect;
- candidates: proxy vertices of one body inside the other's box (+ margin) for repulsion,
  and limb landmarks whose view-averaged contact weight is positive and that lie within
  ``reach`` of the other body for the contact pull;
- active set: every few optimiser steps (``refresh``) each candidate gets its closest
  triangle on the other proxy (among the triangles around its nearest proxy vertices) and
  its inside/outside sign (angle-weighted pseudo-normal at the closest point); between
  refreshes the distance to that triangle is evaluated with gradients w.r.t. both bodies.

Energies (sums of whitened squares, like the rest of the fit):
  repulsion  sum relu(-delta - d)^2 / s_rep^2  (delta: soft tissue may interpenetrate a little)
  contact    sum w relu(d)^2 / s_con^2, w = clamp((p - 0.2) / 0.4, 0, 1), p the landmark's
             person-contact probability averaged over the views that see the person.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from mamma_kit.body import skeleton as sk
from mamma_kit.body.proxy import closest_point_on_triangle, edge_neighbours, winding_number

CLOSEST_BATCH = 4096  # points whose closest triangle is searched at once

LIMB_PARTS = ("left_upper_arm", "right_upper_arm", "left_lower_arm", "right_lower_arm", "left_hand", "right_hand",
              "left_upper_leg", "right_upper_leg", "left_lower_leg", "right_lower_leg", "left_foot", "right_foot")


@dataclass
class ContactConfig:
    delta: float = 0.002  # m of allowed interpenetration
    sigma_rep: float = 0.002  # m
    sigma_con: float = 0.005  # m
    p_lo: float = 0.2
    p_span: float = 0.4
    margin: float = 0.02  # m around the other's box
    reach: float = 0.10  # m: contact landmarks farther than this from the other body are not pulled
    deep: float = 0.02  # m: penetrations are looked for this deep below the other's surface
    hand_stride: int = 2  # every n-th hand vertex joins the repulsion points
    refresh_every: int = 2  # Gauss-Newton iterations between active-set refreshes
    max_points: int = 150  # repulsion points per frame and pair (the deepest)
    k_vertices: int = 2


def contact_weights(contact: np.ndarray, present: np.ndarray, cfg: ContactConfig) -> np.ndarray:
    """(C, P, T, L) per-view contact probabilities -> pull weights (P, T, L): the mean over
    the views that see the person, mapped by clamp((p - p_lo) / p_span, 0, 1)."""
    n = present.sum(0)  # (P, T)
    p = (contact * present[..., None]).sum(0) / np.maximum(n, 1)[..., None]
    return np.clip((p - cfg.p_lo) / cfg.p_span, 0.0, 1.0) * (n > 0)[..., None]


def vertex_faces(faces: np.ndarray, n_verts: int) -> np.ndarray:
    """(Nv, D) faces around each vertex, padded with -1."""
    f = np.repeat(np.arange(len(faces)), 3)
    v = faces.reshape(-1)
    order = np.argsort(v, kind="stable")
    v, f = v[order], f[order]
    counts = np.bincount(v, minlength=n_verts)
    D = counts.max()
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(v)) - start[v]
    out = np.full((n_verts, D), -1, np.int64)
    out[v, slot] = f
    return out


def pseudo_normals(verts: torch.Tensor, faces: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Batched face normals (B, F, 3) and angle-weighted vertex normals (B, Nv, 3)."""
    t = verts[:, faces]  # (B, F, 3, 3)
    n = torch.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0], dim=-1)
    n = n / n.norm(dim=-1, keepdim=True).clamp(min=1e-20)
    vn = torch.zeros_like(verts)
    for k in range(3):  # the three corners of every face at once
        e1 = t[:, :, (k + 1) % 3] - t[:, :, k]
        e2 = t[:, :, (k + 2) % 3] - t[:, :, k]
        cosang = (e1 * e2).sum(-1) / (e1.norm(dim=-1) * e2.norm(dim=-1)).clamp(min=1e-20)
        vn.index_add_(1, faces[:, k], n * torch.arccos(cosang.clamp(-1, 1)).unsqueeze(-1))
    return n, vn


@dataclass
class ActiveSet:
    """Cached candidates of one ordered pair of people (a's points against b's proxy).

    frame (n,) index into the gated frames; point (n,) proxy vertex of a (repulsion) or
    landmark index (contact, see ``is_landmark``); face (n,) triangle of b's proxy;
    sign (n,) +1 outside / -1 inside; weight (n,) contact pull weight (0 for repulsion)."""

    a: int
    b: int
    frame: torch.Tensor
    point: torch.Tensor
    is_landmark: torch.Tensor
    face: torch.Tensor
    sign: torch.Tensor
    weight: torch.Tensor


class ContactModel:
    def __init__(self, model, cfg: ContactConfig):
        self.cfg = cfg
        proxy = model.proxy
        self.proxy_ids = proxy.vertex_ids
        self.faces = torch.as_tensor(proxy.faces)
        self.nb = torch.as_tensor(proxy.neighbours if proxy.neighbours is not None else edge_neighbours(proxy.faces))
        self.vf = torch.as_tensor(vertex_faces(proxy.faces, len(proxy.vertex_ids)))
        hands = [sk.PART_NAMES.index(p) for p in ("left_hand", "right_hand")]
        fpart = np.asarray(model.vertex_part)[proxy.vertex_ids[proxy.faces]]  # (F, 3)
        self.fold_face = torch.as_tensor(np.where((fpart == hands[0]).any(1), 1, np.where((fpart == hands[1]).any(1), 2, 0)))
        lm_part = np.asarray(model.vertex_part)[model.landmark_ids]
        self.limb = torch.as_tensor(np.isin(lm_part, [sk.PART_NAMES.index(p) for p in LIMB_PARTS]))

    @staticmethod
    def gate(proxy_verts: torch.Tensor, margin: float = 0.0) -> np.ndarray:
        """proxy_verts (P, T, Nv, 3) -> (T,) frames where some pair's boxes intersect."""
        lo = proxy_verts.amin(2) - margin
        hi = proxy_verts.amax(2) + margin
        P = proxy_verts.shape[0]
        out = torch.zeros(proxy_verts.shape[1], dtype=torch.bool)
        for a in range(P):
            for b in range(a + 1, P):
                out |= ((torch.minimum(hi[a], hi[b]) - torch.maximum(lo[a], lo[b])) > 0).all(-1)
        return out.numpy()

    @torch.no_grad()
    def _closest(self, pts: torch.Tensor, verts_b: torch.Tensor, fidx: torch.Tensor,
                 near_ids: torch.Tensor | None = None):
        """pts (n, 3), verts_b (G, Nv, 3), fidx (n,) frame of each point -> face (n,), sign (n,), dist (n,)."""
        n = len(pts)
        nf, nv = pseudo_normals(verts_b, self.faces)
        near = torch.empty(n, self.cfg.k_vertices, dtype=torch.long) if near_ids is None else near_ids
        for g in (torch.unique(fidx).tolist() if near_ids is None else []):  # nearest proxy vertices, per frame
            sel = torch.nonzero(fidx == g).flatten()
            near[sel] = torch.topk(torch.cdist(pts[sel], verts_b[g]), self.cfg.k_vertices, dim=1,
                                   largest=False).indices
        # the closest of the triangles around them, CLOSEST_BATCH points at a time (each point's own
        # search: the candidates' arrays of crowded frames would hold gigabytes at once)
        f = torch.empty(n, dtype=torch.long)
        reg = torch.empty(n, dtype=torch.long)
        qb = torch.empty(n, 3, dtype=pts.dtype)
        dist2 = torch.empty(n, dtype=pts.dtype)
        for a in range(0, n, CLOSEST_BATCH):
            sl = slice(a, min(a + CLOSEST_BATCH, n))
            cand = self.vf[near[sl]].reshape(sl.stop - a, -1)  # (m, k * D) triangles around them
            valid = cand >= 0
            cand = cand.clamp(min=0)
            tri = verts_b[fidx[sl, None, None], self.faces[cand]]  # (m, kD, 3, 3)
            q, region = closest_point_on_triangle(pts[sl, None], tri[..., 0, :], tri[..., 1, :], tri[..., 2, :],
                                                  return_region=True)
            dd = ((q - pts[sl, None]) ** 2).sum(-1).masked_fill(~valid, float("inf"))
            best = dd.argmin(1)
            ar = torch.arange(sl.stop - a)
            f[sl], reg[sl], qb[sl], dist2[sl] = cand[ar, best], region[ar, best], q[ar, best], dd[ar, best]
        ar = torch.arange(n)
        # pseudo-normal of the closest feature: face, vertex, or edge (sum of its two faces)
        pn = nf[fidx, f]
        fv = self.faces[f]
        isv = (reg >= 1) & (reg <= 3)
        pn = torch.where(isv[:, None], nv[fidx, fv[ar, (reg - 1).clamp(0, 2)]], pn)
        ise = reg >= 4
        other = self.nb[f, (reg - 4).clamp(0, 2)].clamp(min=0)
        pn = torch.where(ise[:, None], nf[fidx, f] + nf[fidx, other], pn)
        sign = torch.where(((pts - qb) * pn).sum(-1) < 0, -1.0, 1.0)
        dist = dist2.sqrt()
        # a posed, decimated proxy folds onto itself at curled fingers, where the pseudo-normal's
        # sign can be wrong: there, confirm every "inside" and every point within 1 cm of the
        # surface by the generalized winding number (robust to folds; O(triangles) per point,
        # so only where it is needed)
        check = torch.nonzero((sign < 0) & (self.fold_face[f] > 0)).flatten()
        if len(check):
            key = fidx[check] * 3 + self.fold_face[f[check]]  # per frame and hand
            for kg in torch.unique(key).tolist():
                g = kg // 3
                sel = check[key == kg]
                tris = verts_b[g][self.faces]
                # the surface within 10 cm around the points: a hand and its wrist, whose open
                # end subtends a small solid angle from the fingers, so the winding number of
                # this patch decides inside / outside like the whole mesh's, at a tenth of the cost
                c = pts[sel].mean(0)
                rad = float((pts[sel] - c).norm(dim=-1).max()) + 0.10
                near_f = (tris.mean(1) - c).norm(dim=-1) < rad
                inside = winding_number(pts[sel], tris[near_f], chunk=256) > 0.5
                sign[sel] = torch.where(inside, -1.0, 1.0)
        return f, sign, dist

    @torch.no_grad()
    def refresh(self, proxy_verts: torch.Tensor, landmarks: torch.Tensor, weights: torch.Tensor,
                points: torch.Tensor | None = None) -> list[ActiveSet]:
        """proxy_verts (P, G, Nv, 3) and landmarks (P, G, L, 3) at the gated frames, pull
        weights (P, G, L) -> active sets for every ordered pair. ``points`` (P, G, Nc, 3): the
        repulsion points (default: the proxy vertices); ActiveSet.point indexes them."""
        cfg = self.cfg
        P, G = proxy_verts.shape[:2]
        points = proxy_verts if points is None else points
        lo = proxy_verts.amin(2) - cfg.margin
        hi = proxy_verts.amax(2) + cfg.margin
        sets = []
        for a in range(P):
            for b in range(P):
                if a == b:
                    continue
                inside_box = ((points[a] >= lo[b][:, None]) & (points[a] <= hi[b][:, None])).all(-1)
                fr_r, pt_r = torch.nonzero(inside_box, as_tuple=True)
                w = weights[a] * self.limb.to(weights.dtype)
                fr_c, pt_c = torch.nonzero(w > 0, as_tuple=True)
                pts = torch.cat([points[a][fr_r, pt_r], landmarks[a][fr_c, pt_c]])
                fr = torch.cat([fr_r, fr_c])
                is_lm = torch.cat([torch.zeros(len(fr_r), dtype=torch.bool), torch.ones(len(fr_c), dtype=torch.bool)])
                point = torch.cat([pt_r, pt_c])
                wt = torch.cat([torch.zeros(len(fr_r)), w[fr_c, pt_c].float()])
                if len(pts) == 0:
                    continue
                # only points near b's surface need the triangle search: the proxy's edges are
                # ~3 cm, so a point within the reach of its surface is within reach + 3 cm of a
                # vertex (points deeper inside than that are not caught: rare, and caught once
                # the repulsion has pushed the shallower ones out)
                near = torch.zeros(len(pts), dtype=torch.bool)
                nn = torch.zeros(len(pts), cfg.k_vertices, dtype=torch.long)
                lim = np.where(is_lm.numpy(), cfg.reach + 0.03, cfg.deep + 0.03)
                pts_np, pb_np = pts.numpy(), proxy_verts[b].numpy()
                for g in torch.unique(fr).tolist():  # a k-d tree of b's proxy per frame
                    sel = torch.nonzero(fr == g).flatten().numpy()
                    dn, ni = cKDTree(pb_np[g]).query(pts_np[sel], k=cfg.k_vertices)
                    near[sel] = torch.as_tensor(dn[:, 0] < lim[sel])
                    nn[sel] = torch.as_tensor(ni, dtype=torch.long)
                pts, fr, is_lm, point, wt, nn = pts[near], fr[near], is_lm[near], point[near], wt[near], nn[near]
                if len(pts) == 0:
                    continue
                face, sign, dist = self._closest(pts.float(), proxy_verts[b].float(), fr, nn)
                keep = torch.where(is_lm, (dist < cfg.reach) & (sign > 0),  # pull only what is outside and near
                                   (sign < 0) | (dist < cfg.margin))
                # where bodies overlap a lot, the deepest points per frame carry the repulsion
                # (neighbouring points move together; caps the work per frame)
                rep = keep & ~is_lm
                depth = torch.where(rep, sign * dist, torch.full_like(dist, float("inf")))
                for g in torch.unique(fr[rep]).tolist():
                    sel = torch.nonzero(rep & (fr == g)).flatten()
                    if len(sel) > cfg.max_points:
                        drop = sel[torch.argsort(depth[sel])[cfg.max_points:]]
                        keep[drop] = False
                sets.append(ActiveSet(a, b, fr[keep], point[keep], is_lm[keep], face[keep], sign[keep], wt[keep]))
        return sets

    def energy(self, sets: list[ActiveSet], proxy_verts: torch.Tensor, landmarks: torch.Tensor) -> dict:
        """Repulsion and contact energies (differentiable) and counts for the report."""
        cfg = self.cfg
        rep = proxy_verts.new_zeros((), dtype=torch.float64)
        con = proxy_verts.new_zeros((), dtype=torch.float64)
        n_in = 0
        depth = 0.0
        for s in sets:
            pa = torch.where(s.is_landmark[:, None], landmarks[s.a][s.frame, s.point.clamp(max=landmarks.shape[2] - 1)],
                             proxy_verts[s.a][s.frame, s.point.clamp(max=proxy_verts.shape[2] - 1)])
            tri = proxy_verts[s.b][s.frame[:, None], self.faces[s.face]]  # (n, 3, 3)
            q = closest_point_on_triangle(pa, tri[:, 0], tri[:, 1], tri[:, 2])
            d = s.sign * torch.sqrt(((pa - q) ** 2).sum(-1) + 1e-12)
            r = torch.relu(-cfg.delta - d) * (~s.is_landmark)
            rep = rep + (r * r).sum(dtype=torch.float64) / cfg.sigma_rep ** 2
            c = torch.relu(d) * s.weight
            con = con + (c * torch.relu(d)).sum(dtype=torch.float64) / cfg.sigma_con ** 2
            with torch.no_grad():
                inside = (d < 0) & ~s.is_landmark
                n_in += int(inside.sum())
                depth += float((-d[inside]).sum())
        return {"repulsion": rep, "contact": con, "inside_points": n_in,
                "mean_depth_mm": 1000 * depth / max(n_in, 1)}


def barycentric(q: torch.Tensor, tri: torch.Tensor) -> torch.Tensor:
    """Barycentric coordinates (E, 3) of points q (E, 3) on their triangles' planes (E, 3, 3)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, q - a
    d00, d01, d11 = (v0 * v0).sum(-1), (v0 * v1).sum(-1), (v1 * v1).sum(-1)
    d20, d21 = (v2 * v0).sum(-1), (v2 * v1).sum(-1)
    den = (d00 * d11 - d01 * d01).clamp(min=1e-20)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return torch.stack([1 - v - w, v, w], -1)


class ContactTerms:
    """Stage 4's contact and repulsion terms for the Gauss-Newton solver.

    The points are the proxy vertices and landmarks of every person (one kinematics over
    both sets); the active set (contact.ActiveSet, refreshed every ``refresh_every``
    iterations) pairs a point of one person with a triangle of another. Linearised along
    the unit normal n from the closest point q to the point x, d(delta) ~ d + n.(dx - dq):
    each pair gives one row for the point's person (lever arms of x) and one for the
    triangle's person (lever arms of its three vertices, weighted by q's barycentric
    coordinates), in the same frame."""

    def __init__(self, model, cfg: ContactConfig, frames: np.ndarray, pull_w: torch.Tensor, active: tuple):
        from mamma_kit.fitting.kinematics import BodyKinematics

        self.cm = ContactModel(model, cfg)
        self.cfg = cfg
        self.Np = len(self.cm.proxy_ids)
        # repulsion points: the proxy's vertices plus the hands' own vertices (fingers are too
        # thin for the proxy, and hands are where people touch); then the landmarks (pull)
        hands = [sk.PART_NAMES.index(p) for p in ("left_hand", "right_hand")]
        hand_ids = np.setdiff1d(np.flatnonzero(np.isin(model.vertex_part, hands)), self.cm.proxy_ids)
        self.coll_ids = np.concatenate([self.cm.proxy_ids, hand_ids[::cfg.hand_stride]])
        self.Nc = len(self.coll_ids)
        self.kin = BodyKinematics(model, np.concatenate([self.coll_ids, model.landmark_ids]))
        self.frames = torch.as_tensor(frames)
        self.pull_w = pull_w  # (P, T, L)
        act = np.asarray(active, np.int64)
        pos = np.full(self.kin.J + 1, -1, np.int64)
        pos[act] = np.arange(len(act))
        self.pos = torch.as_tensor(pos)
        self.n = 3 * len(act) + 3
        self.sets: list[ActiveSet] = []
        self.stats = {"inside_points": 0, "pairs": 0}  # of the last evaluate / refresh
        self.refreshes = 0  # refresh() calls so far
        self.inside_points_first: int | None = None  # penetrating points at the first refresh

    def use_frames(self, frames: np.ndarray) -> None:
        """Restrict the terms to these frames (e.g. ``contact_frames``'s); clears the active set."""
        self.frames = torch.as_tensor(frames)
        self.sets = []

    @torch.no_grad()
    def contact_frames(self, f, betas, transl) -> np.ndarray:
        """Frames (indices into the pass's T) among the current ones where some pair's
        boxes, from the posed proxies and a margin, intersect (ContactModel.gate)."""
        cp, _ = self.all_points(f, betas, transl)
        return self.frames.numpy()[ContactModel.gate(cp[:, :, :self.Np], margin=self.cfg.margin)]

    def all_points(self, f, betas, transl) -> tuple[torch.Tensor, torch.Tensor]:
        """Posed collision points (P, G, Nc, 3) (proxy vertices first) and landmarks (P, G, L, 3)
        at the terms' G frames, from a forward pass f (kinematics.Posed) of the same poses."""
        from mamma_kit.body.lbs import skin_shared_points

        _, v0 = self.kin.rest(betas, torch.float32)  # (P, U, 3)
        A = torch.cat([f.G, f.tA.unsqueeze(-1)], -1)[:, self.frames]  # (P, G, 55, 3, 4)
        # one GEMM per person over all its gated frames (body.lbs's shared-rest-points blend)
        v = skin_shared_points(v0, A.flatten(-2), self.kin.f32["W"]) + transl.float()[:, self.frames, None]
        return v[:, :, :self.Nc], v[:, :, self.Nc:]

    @torch.no_grad()
    def refresh(self, f, betas, transl, force: bool = False) -> None:
        """Re-pair the points with the other bodies' triangles every ``refresh_every`` calls
        (or when ``force``d or empty). The first call also records the penetrating points
        at that state in ``inside_points_first`` (the stage's starting count)."""
        self.refreshes += 1
        if self.sets and not force and (self.refreshes - 1) % self.cfg.refresh_every:
            return
        cp, lm = self.all_points(f, betas, transl)
        self.sets = self.cm.refresh(cp[:, :, :self.Np], lm, self.pull_w[:, self.frames], points=cp)
        self.stats["pairs"] = int(sum(len(s.frame) for s in self.sets))
        if self.refreshes == 1:
            self.evaluate(f, betas, transl, jac=False)
            self.inside_points_first = self.stats["inside_points"]

    def _pairs(self):
        s = self.sets
        if not s:
            return None
        cat = lambda k: torch.cat([getattr(x, k) for x in s])  # noqa: E731
        a = torch.cat([torch.full((len(x.frame),), x.a) for x in s])
        b = torch.cat([torch.full((len(x.frame),), x.b) for x in s])
        is_lm = cat("is_landmark")
        ui = torch.where(is_lm, self.Nc + cat("point"), cat("point"))
        return a, b, self.frames[cat("frame")], ui, cat("face"), cat("sign"), cat("weight"), is_lm

    def evaluate(self, f, betas, transl, jac: bool):
        """Energy (scalar, float64) [and per-block normal-equation additions (P, T, n, n), (P, T, n)]."""
        pr = self._pairs()
        P, T = transl.shape[:2]
        if pr is None:
            z = torch.zeros((), dtype=torch.float64)
            return (z, None, None) if jac else z
        a, b, t, ui, face, sign, w, is_lm = pr
        cfg = self.cfg
        x, ux = self.kin.points(f, betas, transl, a, t, ui, jac=jac)
        tv = self.cm.faces[face]  # (E, 3) proxy vertex ids = U indices
        E = len(a)
        tri, ut = self.kin.points(f, betas, transl, b.repeat_interleave(3), t.repeat_interleave(3), tv.reshape(-1),
                                  jac=jac)
        tri = tri.reshape(E, 3, 3)
        q = closest_point_on_triangle(x, tri[:, 0], tri[:, 1], tri[:, 2])
        diff = x - q
        dist = diff.norm(dim=-1).clamp(min=1e-9)
        d = sign * dist
        nrm = diff * (sign / dist)[:, None]  # d d / d x
        rep_on = ~is_lm & (d < -cfg.delta)
        con_on = is_lm & (d > 0)
        c = torch.where(rep_on, torch.full_like(d, 1 / cfg.sigma_rep),
                        torch.where(con_on, w.sqrt() / cfg.sigma_con, torch.zeros_like(d)))
        e = torch.where(rep_on, (d + cfg.delta), torch.where(con_on, d, torch.zeros_like(d))) * c
        energy = (e.double() ** 2).sum()
        with torch.no_grad():
            inside = ~is_lm & (d < 0)
            self.stats["inside_points"] = int(inside.sum())
        if not jac:
            return energy
        keep = c > 0
        if not bool(keep.any()):
            return energy, None, None
        # rows of the linearised residual e + c n.(J_x da - J_q db), in "min |r - A delta|^2" form
        bary = barycentric(q, tri)  # (E, 3)
        ka = keep.nonzero().flatten()
        A_a = point_rows(self.kin, self.pos, self.n, ux[ka][:, None], ui[ka][:, None], c[ka][:, None], nrm[ka])
        A_b = point_rows(self.kin, self.pos, self.n, ut.reshape(E, 3, -1, 3)[ka], tv[ka],
                         -(c[ka][:, None] * bary[ka]), nrm[ka])
        # each pair's residual is shared by two people solved side by side (block Jacobi): each
        # side takes half of the correction (doubled curvature), so together they do not overshoot
        Nadd, radd = accumulate_rows(torch.cat([A_a, A_b]), torch.cat([a[ka] * T + t[ka], b[ka] * T + t[ka]]),
                                     torch.cat([-e[ka], -e[ka]]), P, T, self.n, curvature=2.0)
        return energy, Nadd, radd


def point_rows(kin, pos: torch.Tensor, n: int, u: torch.Tensor, vid: torch.Tensor, coef: torch.Tensor,
               nrm: torch.Tensor) -> torch.Tensor:
    """Jacobian rows (k, n) of sum_v coef_v n.x_v for k entries, each over V vertices.

    u (k, V, M, 3) lever arms, vid (k, V) vertex ids (for their influence slots), coef (k, V),
    nrm (k, 3). A world rotation eps_j moves x by eps_j x u, so n.dx = eps_j.(u x n)."""
    k = len(u)
    A = torch.zeros(k, n)
    if k == 0:
        return A
    val = torch.cross(u, nrm[:, None, None, :].expand_as(u), dim=-1) * coef[..., None, None]  # (k, V, M, 3)
    col = pos[kin.infl[vid]]  # (k, V, M) active position or -1
    ok = col >= 0
    kk = torch.arange(k)[:, None, None].expand_as(col)
    # index_add_ on the flat rows: it adds the entries that share a slot in index order (torch's
    # index_put_(accumulate=True) on the CPU adds them in whatever order its threads reach them,
    # which changed the fit in the last bits from run to run)
    flat = A.view(-1)
    for dim in range(3):
        flat.index_add_(0, kk[ok] * n + 3 * col[ok] + dim, val[..., dim][ok].to(A.dtype))
    A[:, -3:] += nrm * coef.sum(1, keepdim=True)
    return A


def accumulate_rows(A: torch.Tensor, blk: torch.Tensor, r: torch.Tensor, P: int, T: int, n: int,
                    curvature: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-block normal-equation additions (P, T, n, n), (P, T, n) from rows A (k, n) of
    blocks blk (k,) (= person * T + frame) with residuals r (k,)."""
    Nadd = torch.zeros(P * T, n, n, dtype=torch.float64)
    radd = torch.zeros(P * T, n, dtype=torch.float64)
    if len(blk):
        order = torch.argsort(blk)
        blk, A, r = blk[order], A[order].double(), r[order].double()
        ub, counts = torch.unique_consecutive(blk, return_counts=True)
        slot = torch.arange(len(blk)) - torch.repeat_interleave(torch.cumsum(counts, 0) - counts, counts)
        bi = torch.repeat_interleave(torch.arange(len(ub)), counts)
        Ap = torch.zeros(len(ub), int(counts.max()), n, dtype=torch.float64)
        rp = torch.zeros(len(ub), int(counts.max()), dtype=torch.float64)
        Ap[bi, slot] = A
        rp[bi, slot] = r
        Nadd[ub] = curvature * (Ap.transpose(1, 2) @ Ap)
        radd[ub] = (Ap.transpose(1, 2) @ rp[..., None])[..., 0]
    return Nadd.reshape(P, T, n, n), radd.reshape(P, T, n)


class FloorTerms:
    """Optional floor terms (world floor at z = 0): foot landmarks below the floor are pushed
    up, and those whose view-averaged floor-contact weight is positive are pulled onto it:
    sum relu(-z)^2 / s^2 + sum w z^2 / s^2, for one person at a time (no coupling)."""

    def __init__(self, kin, foot: np.ndarray, weight: torch.Tensor, sigma: float, active: tuple):
        self.kin, self.sigma = kin, sigma
        self.foot = torch.as_tensor(foot)
        self.weight = weight  # (P, T, L)
        act = np.asarray(active, np.int64)
        pos = np.full(kin.J + 1, -1, np.int64)
        pos[act] = np.arange(len(act))
        self.pos = torch.as_tensor(pos)
        self.n = 3 * len(act) + 3

    def refresh(self, f, betas, transl) -> None:
        pass

    def evaluate(self, f, betas, transl, jac: bool):
        P, T = transl.shape[:2]
        z = f.v[:, :, self.foot, 2]  # (P, T, F)
        w = self.weight[:, :, self.foot]
        c = torch.where(z < 0, torch.full_like(z, 1 / self.sigma), w.sqrt() / self.sigma)
        e = c * z
        energy = (e.double() ** 2).sum()
        if not jac:
            return energy
        pi, ti, li = torch.nonzero(c > 0, as_tuple=True)
        if not len(pi):
            return energy, None, None
        _, u = self.kin.points(f, betas, transl, pi, ti, self.foot[li], jac=True)
        nrm = torch.tensor([0.0, 0.0, 1.0]).expand(len(pi), 3)
        A = point_rows(self.kin, self.pos, self.n, u[:, None], self.foot[li][:, None], c[pi, ti, li][:, None], nrm)
        return (energy, *accumulate_rows(A, pi * T + ti, -e[pi, ti, li], P, T, self.n))


class Terms:
    """Several extra terms as one (GNConfig.extra)."""

    def __init__(self, parts: list):
        self.parts = parts

    def refresh(self, f, betas, transl) -> None:
        for p in self.parts:
            p.refresh(f, betas, transl)

    def evaluate(self, f, betas, transl, jac: bool):
        out = [p.evaluate(f, betas, transl, jac) for p in self.parts]
        if not jac:
            return sum(out)
        E = sum(o[0] for o in out)
        Ns = [o for o in out if o[1] is not None]
        if not Ns:
            return E, None, None
        return E, sum(o[1] for o in Ns), sum(o[2] for o in Ns)
