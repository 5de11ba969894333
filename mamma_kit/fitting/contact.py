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

from mamma_kit.body import skeleton as sk
from mamma_kit.body.proxy import closest_point_on_triangle, edge_neighbours

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
    k_vertices: int = 4


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
    def _closest(self, pts: torch.Tensor, verts_b: torch.Tensor, fidx: torch.Tensor):
        """pts (n, 3), verts_b (G, Nv, 3), fidx (n,) frame of each point -> face (n,), sign (n,), dist (n,)."""
        n = len(pts)
        nf, nv = pseudo_normals(verts_b, self.faces)
        near = torch.empty(n, self.cfg.k_vertices, dtype=torch.long)
        for g in torch.unique(fidx).tolist():  # nearest proxy vertices, one small cdist per frame
            sel = torch.nonzero(fidx == g).flatten()
            near[sel] = torch.topk(torch.cdist(pts[sel], verts_b[g]), self.cfg.k_vertices, dim=1, largest=False).indices
        cand = self.vf[near].reshape(n, -1)  # (n, k * D) triangles around them
        valid = cand >= 0
        cand = cand.clamp(min=0)
        tri = verts_b[fidx[:, None, None], self.faces[cand]]  # (n, kD, 3, 3)
        q, region = closest_point_on_triangle(pts[:, None], tri[..., 0, :], tri[..., 1, :], tri[..., 2, :],
                                              return_region=True)
        dd = ((q - pts[:, None]) ** 2).sum(-1).masked_fill(~valid, float("inf"))
        best = dd.argmin(1)
        ar = torch.arange(n)
        f = cand[ar, best]
        reg = region[ar, best]
        qb = q[ar, best]
        # pseudo-normal of the closest feature: face, vertex, or edge (sum of its two faces)
        pn = nf[fidx, f]
        fv = self.faces[f]
        isv = (reg >= 1) & (reg <= 3)
        pn = torch.where(isv[:, None], nv[fidx, fv[ar, (reg - 1).clamp(0, 2)]], pn)
        ise = reg >= 4
        other = self.nb[f, (reg - 4).clamp(0, 2)].clamp(min=0)
        pn = torch.where(ise[:, None], nf[fidx, f] + nf[fidx, other], pn)
        sign = torch.where(((pts - qb) * pn).sum(-1) < 0, -1.0, 1.0)
        return f, sign, dd[ar, best].sqrt()

    @torch.no_grad()
    def refresh(self, proxy_verts: torch.Tensor, landmarks: torch.Tensor, weights: torch.Tensor) -> list[ActiveSet]:
        """proxy_verts (P, G, Nv, 3) and landmarks (P, G, L, 3) at the gated frames, pull
        weights (P, G, L) -> active sets for every ordered pair."""
        cfg = self.cfg
        P, G = proxy_verts.shape[:2]
        lo = proxy_verts.amin(2) - cfg.margin
        hi = proxy_verts.amax(2) + cfg.margin
        sets = []
        for a in range(P):
            for b in range(P):
                if a == b:
                    continue
                inside_box = ((proxy_verts[a] >= lo[b][:, None]) & (proxy_verts[a] <= hi[b][:, None])).all(-1)
                fr_r, pt_r = torch.nonzero(inside_box, as_tuple=True)
                w = weights[a] * self.limb.to(weights.dtype)
                fr_c, pt_c = torch.nonzero(w > 0, as_tuple=True)
                pts = torch.cat([proxy_verts[a][fr_r, pt_r], landmarks[a][fr_c, pt_c]])
                fr = torch.cat([fr_r, fr_c])
                is_lm = torch.cat([torch.zeros(len(fr_r), dtype=torch.bool), torch.ones(len(fr_c), dtype=torch.bool)])
                point = torch.cat([pt_r, pt_c])
                wt = torch.cat([torch.zeros(len(fr_r)), w[fr_c, pt_c].float()])
                if len(pts) == 0:
                    continue
                face, sign, dist = self._closest(pts.float(), proxy_verts[b].float(), fr)
                keep = torch.where(is_lm, (dist < cfg.reach) & (sign > 0),  # pull only what is outside and near
                                   (sign < 0) | (dist < cfg.margin))
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
