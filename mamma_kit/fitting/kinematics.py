"""The body at the fit's landmark vertices with what Gauss-Newton needs: per-vertex lever
arms for every joint that moves it, and the Jacobian w.r.t. the shape coefficients.

Poses are held as local rotation matrices (P, T, 55, 3, 3). A Gauss-Newton step turns joint
j's whole subtree by a small world-frame rotation eps_j about the joint: R_j <- exp([G_par^T
eps_j]) R_j (G_par: the parent's world rotation), which moves a posed vertex by
-[u_lj]x eps_j with u_lj = sum_{k in subtree(j)} w_lk (A_k v_l) - (sum of those w_lk) p_j.
Each vertex depends on the few joints on its skinning joints' chains ("influence" slots,
padded to M per vertex), so the Jacobian is built per body part (parts share their chains)
and the normal equations stay small dense blocks.

The forward pass (``BodyKinematics.forward`` -> ``Posed``) equals body.lbs.pose_restricted
(checked in tests) and runs without autograd; every stage of the fit uses it (body.lbs
stays the reference for the written SMPL-X joints and the reports).

Regressed points (``BodyKinematics(model, regressor=...)``: the fit's 33 keypoints, each a
convex combination X = sum_v c_v V_v of vertices) are exact "virtual vertices" with one rest
position per skinning slot: V_v = sum_j w_vj (G_j v_v + tA_j), so X = sum_j w'_j (G_j y_j +
tA_j) with w'_j = sum_v c_v w_vj and y_j = sum_v c_v w_vj v_v / w'_j (and likewise its shape
and pose correctives). Lever arms and the shape Jacobian follow the same formulas per slot.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from mamma_kit.body import skeleton as sk
from mamma_kit.body.lbs import axis_angle_to_matrix, forward_kinematics

DTYPE = torch.float64  # state (rotations, translations, shapes) and linear solves
CDTYPE = torch.float32  # Jacobians, projections, lever arms: memory traffic dominates here


def skew(v: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrices [v]x."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(*v.shape, 3)


def so3_exp(w: torch.Tensor) -> torch.Tensor:
    return axis_angle_to_matrix(w)


def so3_log(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) -> axis-angle (..., 3), stable near 0 and pi.

    The angle comes from atan2(|vee| / 2, (tr - 1) / 2), accurate everywhere (arccos is
    not near 0 and pi). Near pi, vee = 2 sin(th) a vanishes, so the axis is read from the
    symmetric part: (R + R^T) / 2 = cos(th) I + (1 - cos(th)) a a^T, its sign from vee."""
    tr = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    vee = torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = vee.norm(dim=-1) / 2
    cos = (tr - 1) / 2
    th = torch.atan2(sin, cos)
    small = th < 1e-4
    fac = torch.where(small, 0.5 + th * th / 12, th / (2 * torch.where(small, torch.ones_like(sin), sin)))
    w = vee * fac.unsqueeze(-1)
    near_pi = th > np.pi - 1e-2
    if bool(near_pi.any()):
        Rn, cn = R[near_pi], cos[near_pi]
        aa = ((Rn + Rn.transpose(-1, -2)) / 2 - cn[:, None, None] * torch.eye(3, dtype=R.dtype)) \
            / (1 - cn)[:, None, None]
        i = torch.diagonal(aa, dim1=-2, dim2=-1).argmax(-1)
        col = aa[torch.arange(len(i)), :, i]
        a = col / col.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        s = torch.sign((a * vee[near_pi]).sum(-1))
        s = torch.where(s == 0, torch.ones_like(s), s)
        w = w.clone()
        w[near_pi] = a * (th[near_pi] * s).unsqueeze(-1)
    return w


def so3_left_jacobian_inv(w: torch.Tensor) -> torch.Tensor:
    """J_l^{-1}(w) (..., 3, 3): log(exp(d) exp(w)) ~ w + J_l^{-1}(w) d for small d."""
    th2 = (w * w).sum(-1)
    th = torch.sqrt(th2.clamp(min=1e-24))
    small = th < 1e-4
    ths = torch.where(small, torch.ones_like(th), th)
    c = torch.where(small, torch.full_like(th, 1.0 / 12),
                    1 / ths ** 2 - (1 + torch.cos(ths)) / (2 * ths * torch.sin(ths).clamp(min=1e-12)))
    W = skew(w)
    eye = torch.eye(3, dtype=w.dtype).expand(W.shape)
    return eye - 0.5 * W + c[..., None, None] * (W @ W)


class Posed(NamedTuple):
    """One forward pass of BodyKinematics (P people, T frames, N points, M influence slots,
    B shape coefficients), in the pass's dtype:

    v (P, T, N, 3) posed points; joints (P, T, 55, 3) posed joints (with translation);
    G (P, T, 55, 3, 3) world rotations; p (P, T, 55, 3) joint positions (without
    translation); tA (P, T, 55, 3) translation of each joint transform; Jr (P, 55, 3) rest
    joints; rot (P, T, 55, 3, 3) local rotations. With ``jac``: u (P, T, N, M, 3) lever arms
    per influence slot, u_joints (P, T, 55, Mj, 3) the joints' own; with ``shape_jac``:
    Jb (P, T, N, 3, B) = d v / d betas (None otherwise)."""

    v: torch.Tensor
    joints: torch.Tensor
    G: torch.Tensor
    p: torch.Tensor
    tA: torch.Tensor
    Jr: torch.Tensor
    rot: torch.Tensor
    u: torch.Tensor | None = None
    u_joints: torch.Tensor | None = None
    Jb: torch.Tensor | None = None


@dataclass
class Group:
    """Landmarks of one body part and the parameter columns they touch.

    lm (n,) landmark indices; cols (c = 3 J_g + 3,) parameter columns (the group's joint
    blocks, then translation); the group Jacobian is a flat (n * 3 * c) array per block:
    template (n * 3 * c,) holds its constant entries (translation = identity), and the
    six non-zero entries of -[u]x of every valid influence slot (l_sel, m_sel) go to
    positions pos (n_valid, 6) with signs sign (6,) taken from u components comp (6,).
    nflat: (c * c,) flat positions of the group's normal matrix in the full one."""

    lm: torch.Tensor
    cols: torch.Tensor
    l_sel: torch.Tensor
    m_sel: torch.Tensor
    pos: torch.Tensor
    template: torch.Tensor
    nflat: torch.Tensor

    @property
    def ncols(self) -> int:
        return len(self.cols)


# -[u]x = [[0, uz, -uy], [-uz, 0, ux], [uy, -ux, 0]]: (row, col, u component, sign)
_SKEW_NEG = [(0, 1, 2, 1.0), (0, 2, 1, -1.0), (1, 0, 2, -1.0), (1, 2, 0, 1.0), (2, 0, 1, 1.0), (2, 1, 0, -1.0)]
SKEW_COMP = torch.tensor([e[2] for e in _SKEW_NEG])
SKEW_SIGN = torch.tensor([e[3] for e in _SKEW_NEG], dtype=CDTYPE)


class BodyKinematics:
    """Restricted LBS at a vertex set (default: the model's landmarks) with GN structure."""

    def __init__(self, model, vertex_ids: np.ndarray | None = None, regressor=None):
        """``regressor``: body.kp_regressor.KeypointRegressor; the points are then its
        regressed points (see the module doc), ``ids`` each one's heaviest support vertex."""
        rb = model.restricted(vertex_ids) if regressor is None else _regressed_body(model, regressor)
        self.model = model
        self.ids = rb.ids
        self.N = len(self.ids)
        self.per_slot = rb.v_template.ndim == 3  # rest positions (N, K, 3): one per skinning slot
        self.v_template = rb.v_template.to(DTYPE)
        self.shapedirs = rb.shapedirs.to(DTYPE)
        self.posedirs = None if rb.posedirs is None else rb.posedirs.to(DTYPE)
        self.skin_idx = rb.skin_idx
        self.skin_w = rb.skin_w.to(DTYPE)
        self.W = rb.W.to(DTYPE)  # (N, 55)
        self.J_template = model.J_template.to(DTYPE)
        self.J_shapedirs = model.J_shapedirs.to(DTYPE)
        self.parents = model.parents.numpy().astype(np.int64)
        J = len(self.parents)
        self.J = J
        # sub[j, k]: joint k is in the subtree of j (k == j included)
        sub = np.eye(J, dtype=bool)
        for k in range(J):
            a = self.parents[k]
            while a >= 0:
                sub[a, k] = True
                a = self.parents[a]
        self.sub = sub
        # ancestors-or-self excluding the root, for d p / d betas
        self.anc_noroot = torch.as_tensor(sub.T.astype(np.float64) * (np.arange(J) != 0)[None], dtype=DTYPE)
        # influence slots: joints j with sum_k w_lk [skin_k in sub(j)] > 0
        idx = self.skin_idx.numpy()
        w = self.skin_w.numpy()
        coef = sub[:, idx] * w[None]  # (J, N, K)
        s = coef.sum(-1)  # (J, N)
        M = int((s > 1e-9).sum(0).max())
        infl = np.full((self.N, M), J, np.int64)  # J = dummy joint (zero lever)
        cnk = np.zeros((self.N, M, idx.shape[1]))
        for n in range(self.N):  # setup only (once per model)
            js = np.flatnonzero(s[:, n] > 1e-9)
            infl[n, :len(js)] = js
            cnk[n, :len(js)] = coef[js, n]
        self.M = M
        self.infl = torch.as_tensor(infl)
        self.coef = torch.as_tensor(cnk, dtype=DTYPE)
        self.coef_sum = self.coef.sum(-1)  # (N, M)
        self.part = np.asarray(model.vertex_part)[self.ids]
        self._groups: dict = {}
        self._subsets: dict = {}
        # joints as points: joint j moves with every strict ancestor's rotation (lever p_j - p_i)
        anc = [np.flatnonzero(sub[:, j] & (np.arange(J) != j)) for j in range(J)]
        Mj = max(len(a) for a in anc)
        self.joint_infl = torch.as_tensor(np.array([np.r_[a, np.full(Mj - len(a), J)] for a in anc], np.int64))
        c = lambda a: None if a is None else a.to(CDTYPE)  # noqa: E731
        self.f32 = {k: c(getattr(self, k)) for k in ("v_template", "shapedirs", "posedirs", "skin_w", "W",
                                                     "J_template", "J_shapedirs", "coef", "coef_sum",
                                                     "anc_noroot")}

    def subset(self, rows: np.ndarray) -> "BodyKinematics":
        """This kinematics at its points ``rows`` only (a vertex set: not regressed points), cached:
        a problem that reads a few points (one limb's) pays for those alone."""
        key = np.asarray(rows, np.int64).tobytes()
        if key not in self._subsets:
            assert not self.per_slot, "regressed points have no subset"
            self._subsets[key] = BodyKinematics(self.model, self.ids[np.asarray(rows, np.int64)])
        return self._subsets[key]

    # ---- shape ------------------------------------------------------------------------
    def rest(self, betas: torch.Tensor, dtype=DTYPE) -> tuple[torch.Tensor, torch.Tensor]:
        """betas (P, B) -> rest joints (P, 55, 3), rest vertices (P, N, 3) (regressed points:
        per skinning slot, (P, N, K, 3))."""
        d = self.f32 if dtype == CDTYPE else self.__dict__
        b = betas.to(dtype)
        J = d["J_template"] + torch.einsum("jdb,pb->pjd", d["J_shapedirs"], b)
        v = d["v_template"] + torch.einsum("n...db,pb->pn...d", d["shapedirs"], b)
        return J, v

    def rest_points(self, betas: torch.Tensor, dtype=DTYPE) -> torch.Tensor:
        """Rest-pose positions (P, N, 3) of the points (regressed points blended over slots)."""
        _, v = self.rest(betas, dtype)
        if not self.per_slot:
            return v
        return (v * self.skin_w.to(dtype)[None, ..., None]).sum(-2)

    # ---- pose -------------------------------------------------------------------------
    @torch.no_grad()
    def forward(self, betas: torch.Tensor, rot: torch.Tensor, transl: torch.Tensor, jac: bool = False,
                shape_jac: bool = False, dtype=CDTYPE) -> Posed:
        """betas (P, B), rot (P, T, 55, 3, 3) local rotations, transl (P, T, 3) -> ``Posed``
        (its doc gives the shapes): the points, joints and joint transforms; with ``jac``
        also the lever arms, with ``shape_jac`` also d v / d betas. Computed in ``dtype``."""
        Jr = self.rest(betas, dtype)[0]
        rot = rot.to(dtype)
        G, p = forward_kinematics(rot, Jr[:, None], self.parents)  # (P, T, 55, 3, 3), (P, T, 55, 3)
        tA = p - (G @ Jr[:, None].unsqueeze(-1)).squeeze(-1)  # translation of each joint transform
        joints_only = Posed(v=None, joints=None, G=G, p=p, tA=tA, Jr=Jr, rot=rot)
        return self.forward_from(joints_only, betas, transl, jac, shape_jac, dtype)

    @torch.no_grad()
    def forward_from(self, f: Posed, betas: torch.Tensor, transl: torch.Tensor, jac: bool = False,
                     shape_jac: bool = False, dtype=CDTYPE) -> Posed:
        """This kinematics' points from another forward pass ``f`` of the same poses (its
        joint transforms G, p, tA, Jr, rot; any vertex set): the keypoints ride on the
        landmarks' forward kinematics. Returns what ``forward`` returns."""
        d = self.f32 if dtype == CDTYPE else self.__dict__
        v0 = self.rest(betas, dtype)[1]
        G, p, tA, Jr, rot = (t.to(dtype) for t in (f.G, f.p, f.tA, f.Jr, f.rot))
        P, T = rot.shape[:2]
        pt = (self.skin_idx.shape[1], 3) if self.per_slot else (3,)
        if self.posedirs is not None:
            feat = (rot[:, :, 1:] - torch.eye(3, dtype=dtype)).flatten(-3)  # (P, T, 486)
            v0 = v0[:, None] + (feat @ d["posedirs"]).reshape(P, T, self.N, *pt)
        else:
            v0 = v0[:, None]
        # x_lk = G_k v_l + tA_k for the K skinning joints of every vertex, as broadcast
        # multiply-adds (a batched 3x3 product per vertex and slot is far slower on a CPU)
        Gk = G[:, :, self.skin_idx]  # (P, T, N, K, 3, 3)
        vv = v0 if self.per_slot else v0.unsqueeze(-2)  # (P, T|1, N, K|1, 3)
        x = tA[:, :, self.skin_idx] + Gk[..., 0] * vv[..., 0:1] + Gk[..., 1] * vv[..., 1:2] + Gk[..., 2] * vv[..., 2:3]
        tr = transl.to(dtype)[:, :, None]
        v = (x * d["skin_w"][..., None]).sum(-2) + tr
        u = u_joints = Jb = None
        if jac:
            pz = torch.cat([p, torch.zeros_like(p[:, :, :1])], 2)  # dummy joint J -> zero
            u = torch.einsum("nmk,ptnkd->ptnmd", d["coef"], x) - d["coef_sum"][..., None] * pz[:, :, self.infl]
            u_joints = p.unsqueeze(-2) - pz[:, :, self.joint_infl]  # (P, T, 55, Mj, 3); dummy slots unused
        if shape_jac:
            Jb = self._shape_jacobian(d, G, Gk, P, T, dtype)
        return Posed(v, p + tr, G, p, tA, Jr, rot, u, u_joints, Jb)

    def _shape_jacobian(self, d: dict, G: torch.Tensor, Gk: torch.Tensor, P: int, T: int, dtype) -> torch.Tensor:
        """d v / d betas (P, T, N, 3, B) from the world rotations G (P, T, 55, 3, 3) and
        their gather at the skinning joints Gk (P, T, N, K, 3, 3)."""
        Sd = d["shapedirs"]  # (N, 3, B), regressed points (N, K, 3, B)
        if self.per_slot:  # each slot's own shape directions under its joint's rotation
            Jb = torch.einsum("nk,ptnkij,nkjb->ptnib", d["skin_w"], Gk, Sd)
        else:
            Gt = torch.einsum("nk,ptkij->ptnij", d["W"], G)  # (P, T, N, 3, 3) blended rotation
            Jb = Gt[..., 0:1] * Sd[:, 0:1] + Gt[..., 1:2] * Sd[:, 1:2] + Gt[..., 2:3] * Sd[:, 2:3]  # (P, T, N, 3, B)
        SJ = d["J_shapedirs"]  # (55, 3, B)
        dSJ = SJ - torch.cat([torch.zeros_like(SJ[:1]), SJ[self.parents[1:]]], 0)
        Gpar = torch.cat([torch.eye(3, dtype=dtype).expand(P, T, 1, 3, 3), G[:, :, self.parents[1:]]], 2)
        D = SJ[0] + torch.einsum("ka,ptaij->ptkij", d["anc_noroot"], Gpar @ dSJ)  # (P, T, 55, 3, B)
        E = D - G @ SJ
        return Jb + torch.einsum("nk,ptkij->ptnij", d["W"], E)

    def points(self, f: Posed, betas: torch.Tensor, transl: torch.Tensor, pi: torch.Tensor, ti: torch.Tensor,
               vi: torch.Tensor, jac: bool = False, dtype=CDTYPE) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Posed vertices for arbitrary entries (person pi, frame ti, vertex vi of this
        kinematics' set), from a forward pass ``f`` (any vertex set) of the same poses:
        (E, 3) positions [and lever arms (E, M, 3)]. No pose correctives (they only
        matter for SMPL-X files and are left to the landmark terms)."""
        d = self.f32 if dtype == CDTYPE else self.__dict__
        b = betas.to(dtype)[pi]
        v0 = d["v_template"][vi] + torch.einsum("e...db,eb->e...d", d["shapedirs"][vi], b)  # (E, 3) or (E, K, 3)
        idx = self.skin_idx[vi]  # (E, K)
        G = f.G[pi[:, None], ti[:, None], idx]  # (E, K, 3, 3)
        vk = v0[:, :, None, :] if self.per_slot else v0[:, None, None, :]
        x = (G * vk).sum(-1) + f.tA[pi[:, None], ti[:, None], idx]  # (E, K, 3)
        v = (x * d["skin_w"][vi][..., None]).sum(1) + transl.to(dtype)[pi, ti]
        if not jac:
            return v, None
        pz = torch.cat([f.p, torch.zeros_like(f.p[:, :, :1])], 2)
        u = torch.einsum("emk,ekd->emd", d["coef"][vi], x) - d["coef_sum"][vi][..., None] * \
            pz[pi[:, None], ti[:, None], self.infl[vi]]
        return v, u

    # ---- Jacobian structure ------------------------------------------------------------
    def groups(self, active: tuple[int, ...]) -> tuple[list[Group], int]:
        """Per-part groups of the vertices for an active joint list; returns (groups, columns)."""
        key = ("v", tuple(active))
        if key not in self._groups:
            self._groups[key] = self._build_groups(active, self.infl.numpy(), self.part)
        return self._groups[key]

    def joint_group(self, active: tuple[int, ...]) -> Group:
        """All 55 joints as one group (the temporal term's points)."""
        key = ("j", tuple(active))
        if key not in self._groups:
            self._groups[key] = self._build_groups(active, self.joint_infl.numpy(), np.zeros(self.J, np.int64))
        return self._groups[key][0][0]

    def _build_groups(self, active, infl: np.ndarray, parts: np.ndarray) -> tuple[list[Group], int]:
        act = np.asarray(active, np.int64)
        pos = np.full(self.J + 1, -1, np.int64)
        pos[act] = np.arange(len(act))
        ncols = 3 * len(act) + 3
        rows = np.array([e[0] for e in _SKEW_NEG])
        colo = np.array([e[1] for e in _SKEW_NEG])
        groups = []
        for part in np.unique(parts):
            lm = np.flatnonzero(parts == part)
            sl = pos[infl[lm]]  # (n, M) active position or -1
            js = np.unique(sl[sl >= 0])
            local = np.full(len(act), -1, np.int64)
            local[js] = np.arange(len(js))
            c = 3 * len(js) + 3
            l_sel, m_sel = np.nonzero(sl >= 0)
            jl = local[sl[l_sel, m_sel]]
            # flat position of entry (l, row a, column 3 jl + b) in an (n, 3, c) array
            fpos = (l_sel[:, None] * 3 + rows[None]) * c + 3 * jl[:, None] + colo[None]
            tmpl = np.zeros((len(lm), 3, c))
            tmpl[:, [0, 1, 2], [c - 3, c - 2, c - 1]] = 1.0
            cols = np.concatenate([(3 * js[:, None] + np.arange(3)).reshape(-1), ncols - 3 + np.arange(3)])
            nflat = (cols[:, None] * ncols + cols[None, :]).reshape(-1)
            groups.append(Group(torch.as_tensor(lm), torch.as_tensor(cols), torch.as_tensor(l_sel),
                                torch.as_tensor(m_sel), torch.as_tensor(fpos.reshape(-1)),
                                torch.as_tensor(tmpl.reshape(-1), dtype=CDTYPE), torch.as_tensor(nflat)))
        return groups, ncols

    def group_jacobian(self, gr: Group, u: torch.Tensor) -> torch.Tensor:
        """(B, n_g * 3, c_g) Jacobian of a group's vertices from lever arms u (P, T, N, M, 3)."""
        P, T = u.shape[:2]
        ug = u[:, :, gr.lm[gr.l_sel], gr.m_sel]  # (P, T, n_valid, 3)
        vals = ug[..., SKEW_COMP] * SKEW_SIGN  # (P, T, n_valid, 6)
        J = gr.template.to(u.dtype).expand(P * T, -1).clone()
        J.index_copy_(1, gr.pos, vals.reshape(P * T, -1))
        return J.view(P * T, len(gr.lm) * 3, gr.ncols)


def rotmats_from_params(params: dict, P: int, T: int) -> torch.Tensor:
    """SMPL-X parameter dict (axis-angle arrays (P, T, n)) -> local rotations (P, T, 55, 3, 3)."""
    aa = torch.zeros(P, T, sk.NUM_JOINTS, 3, dtype=DTYPE)
    off = 0
    for k, n in sk.POSE_PARAMS.items():
        if k in params and params[k] is not None:
            aa[:, :, off // 3: (off + n) // 3] = torch.as_tensor(np.asarray(params[k]), dtype=DTYPE).reshape(P, T, n // 3, 3)
        off += n
    return axis_angle_to_matrix(aa)


@dataclass
class RegressedBody:
    """Restricted-body data of regressed points (see the module doc): ids (N,) each point's
    heaviest support vertex; v_template (N, K, 3) and shapedirs (N, K, 3, B) per skinning
    slot; posedirs (486, N * K * 3) or None; skin_idx, skin_w (N, K); W (N, 55)."""

    ids: np.ndarray
    v_template: torch.Tensor
    shapedirs: torch.Tensor
    posedirs: torch.Tensor | None
    skin_idx: torch.Tensor
    skin_w: torch.Tensor
    W: torch.Tensor


def _regressed_body(model, reg) -> RegressedBody:
    ids, c = np.asarray(reg.ids), np.asarray(reg.weights, np.float64)  # (N, S)
    Wd = model.weights_dense.numpy().astype(np.float64)[ids]  # (N, S, 55)
    cw = c[..., None] * Wd  # (N, S, 55): c_v w_vj
    wj = cw.sum(1)  # (N, 55) blended skinning weight of each joint
    slots = [np.flatnonzero(w > 1e-7) for w in wj]
    K = max(len(s) for s in slots)
    N = len(ids)
    v = model.v_template.numpy().astype(np.float64)[ids]  # (N, S, 3)
    sd = model.shapedirs.numpy().astype(np.float64)[ids]  # (N, S, 3, B)
    pd = None if model.posedirs is None else model.posedirs.numpy().astype(np.float64)[ids]  # (N, S, 3, 486)
    skin_idx = np.zeros((N, K), np.int64)
    skin_w = np.zeros((N, K))
    vt = np.zeros((N, K, 3))
    sdt = np.zeros((N, K, 3, sd.shape[-1]))
    pdt = None if pd is None else np.zeros((N, K, 3, pd.shape[-1]))
    for n in range(N):  # setup only (33 points)
        js = slots[n]
        a = cw[n][:, js] / wj[n, js]  # (S, k): each support vertex's share of the slot
        skin_idx[n, :len(js)] = js
        skin_w[n, :len(js)] = wj[n, js]
        vt[n, :len(js)] = np.einsum("sk,sd->kd", a, v[n])
        sdt[n, :len(js)] = np.einsum("sk,sdb->kdb", a, sd[n])
        if pd is not None:
            pdt[n, :len(js)] = np.einsum("sk,sdf->kdf", a, pd[n])
    skin_w /= skin_w.sum(1, keepdims=True)
    t = lambda a: torch.as_tensor(a, dtype=model.v_template.dtype)  # noqa: E731
    pdf = None if pdt is None else t(pdt.reshape(N * K * 3, -1).T.copy())
    rep = ids[np.arange(N), c.argmax(1)]
    return RegressedBody(rep, t(vt), t(sdt), pdf, torch.as_tensor(skin_idx), t(skin_w), t(wj / wj.sum(1, keepdims=True)))
