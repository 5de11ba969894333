"""Levenberg-Marquardt on the block-sparse reprojection problem (stages 1 and 2).

Unknowns: per person and frame (a block) a small world-frame rotation of every active joint
(see kinematics) and the translation; per person the shape coefficients, shared by all its
frames. The energy is the paper's robust reprojection term

    E = sum_{c,l} p_cl rho(|(mu_cl - Pi_c(V_l)) / sigma_cl|^2),  rho(s2) = g^2 s2 / (s2 + g^2)

(Geman-McClure, quadratic = Gaussian for small residuals, bounded by g^2 for outliers) plus
a light pose prior |theta_j|^2 / s_j^2 on local rotations and the L2 shape prior |beta|^2.
Each iteration linearises (IRLS weights for rho), builds every block's normal matrix from
per-part dense Jacobians (a landmark only moves with the joints on its chain), eliminates
the shared shape by its Schur complement, and accepts each block's step only if the block's
energy drops (per-block damping). The scale g starts large (nearly least squares, a wide
basin from a rough start) and shrinks to its final value (graduated non-convexity).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from mamma_kit.fitting.kinematics import CDTYPE, DTYPE, BodyKinematics, so3_exp, so3_left_jacobian_inv, so3_log
from mamma_kit.fitting.projection import RigTensors


@dataclass
class Obs:
    """Observations as float32 tensors, camera-major: xy, sigma (C, P, T, L, 2), w (C, P, T, L)."""

    xy: torch.Tensor
    sigma: torch.Tensor
    w: torch.Tensor

    def frames(self, s) -> "Obs":
        return Obs(self.xy[:, :, s], self.sigma[:, :, s], self.w[:, :, s])


@dataclass
class State:
    betas: torch.Tensor  # (P, B)
    rot: torch.Tensor  # (P, T, 55, 3, 3)
    transl: torch.Tensor  # (P, T, 3)

    def clone(self) -> "State":
        return State(self.betas.clone(), self.rot.clone(), self.transl.clone())


@dataclass
class GNConfig:
    active: tuple[int, ...]
    iterations: int = 12
    gamma_start: float = 30.0
    gamma_end: float = 4.0
    optimize_betas: bool = False
    shape_weight: float = 1.0
    prior_sigma: np.ndarray | None = None  # (55,) rad; inf = no prior
    landmark_weight: torch.Tensor | None = None  # (L,) multiplies visibility (stage 1: rigid parts)
    tol: float = 1e-5
    mu0: float = 1e-3

    def gamma(self, k: int) -> float:
        if self.iterations <= 1:
            return self.gamma_end
        a = min(1.0, k / max(1, (self.iterations - 1) * 0.6))
        return float(self.gamma_start * (self.gamma_end / self.gamma_start) ** a)


@dataclass
class GNReport:
    energies: list[float] = field(default_factory=list)
    accepted: list[float] = field(default_factory=list)
    iterations: int = 0


def robust(s2: torch.Tensor, gamma: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Geman-McClure rho(s2) and its derivative d rho / d s2 (the IRLS weight)."""
    g2 = gamma * gamma
    den = s2 + g2
    return g2 * s2 / den, (g2 / den) ** 2


class GaussNewton:
    def __init__(self, kin: BodyKinematics, cams: RigTensors, obs: Obs, cfg: GNConfig):
        self.kin, self.cams, self.obs, self.cfg = kin, cams.to(CDTYPE), obs, cfg
        self.act = torch.as_tensor(cfg.active)
        self.groups, self.n = kin.groups(cfg.active)
        w = obs.w.to(CDTYPE)
        if cfg.landmark_weight is not None:
            w = w * cfg.landmark_weight.to(CDTYPE)
        self.w = w
        self.xy = obs.xy.to(CDTYPE)
        self.inv_sigma = (1.0 / obs.sigma).to(CDTYPE)
        ps = np.full(55, np.inf) if cfg.prior_sigma is None else np.asarray(cfg.prior_sigma, float)
        self.prior_w = torch.as_tensor(1.0 / ps[list(cfg.active)] ** 2, dtype=DTYPE)  # (A,)

    # ---- energy ----------------------------------------------------------------------------
    def data_terms(self, v: torch.Tensor, gamma: float, jac: bool):
        """v (P, T, L, 3) -> per-block data energy (P, T) float64 [and H (P,T,L,3,3), g (P,T,L,3)]."""
        v = v.to(CDTYPE)
        if jac:
            uv, Jp, valid = self.cams.project_jacobian(v[None])
        else:
            uv, valid = self.cams.project(v[None])
        r = (self.xy - uv) * self.inv_sigma  # (C, P, T, L, 2)
        s2 = (r * r).sum(-1)
        w = self.w * valid
        rho, drho = robust(s2, gamma)
        E = (w * rho).to(DTYPE).sum((0, 3))
        if not jac:
            return E
        sq = torch.sqrt(w * drho)  # (C, P, T, L)
        Jw = Jp * (self.inv_sigma * sq[..., None])[..., None]  # (C, P, T, L, 2, 3) whitened
        rw = r * sq[..., None]
        C, P, T, L = sq.shape
        Jf = Jw.permute(1, 2, 3, 0, 4, 5).reshape(P * T * L, 2 * C, 3)
        H = (Jf.transpose(1, 2) @ Jf).reshape(P, T, L, 3, 3)
        g = (Jf.transpose(1, 2) @ rw.permute(1, 2, 3, 0, 4).reshape(P * T * L, 2 * C, 1)).reshape(P, T, L, 3)
        return E, H, g

    def prior_terms(self, rot: torch.Tensor, G: torch.Tensor | None = None):
        """Pose prior energy (P, T) [and its normal-equation diagonal blocks, rhs]."""
        th = so3_log(rot[:, :, self.act].to(DTYPE))  # (P, T, A, 3)
        E = ((th * th).sum(-1) * self.prior_w).sum(-1)
        if G is None:
            return E
        par = np.asarray(self.kin.parents)[self.act.numpy()]
        eye = torch.eye(3, dtype=DTYPE).expand(*G.shape[:2], 1, 3, 3)
        Gall = torch.cat([G.to(DTYPE), eye], 2)  # index 55 = identity (root's parent)
        Gpar = Gall[:, :, torch.as_tensor(np.where(par < 0, G.shape[2], par))]
        Jr = so3_left_jacobian_inv(th) @ Gpar.transpose(-1, -2)  # d theta / d eps (P, T, A, 3, 3)
        pw = self.prior_w[:, None, None]
        Nd = pw * (Jr.transpose(-1, -2) @ Jr)
        rhs = -(pw[..., 0] * (Jr.transpose(-1, -2) @ th[..., None])[..., 0])
        return E, Nd, rhs

    def energy(self, st: State, gamma: float) -> torch.Tensor:
        f = self.kin.forward(st.betas, st.rot, st.transl)
        return self.data_terms(f["v"], gamma, jac=False) + self.prior_terms(st.rot)

    # ---- normal equations ------------------------------------------------------------------
    def normal_equations(self, f: dict, H: torch.Tensor, g: torch.Tensor):
        """Normal matrices (B, n, n), right-hand sides (B, n) [and the shape blocks], float64."""
        P, T = H.shape[:2]
        B = P * T
        n = self.n
        N = torch.zeros(B, n * n, dtype=CDTYPE)
        rhs = torch.zeros(B, n, dtype=CDTYPE)
        want_b = self.cfg.optimize_betas
        nb = self.kin.shapedirs.shape[-1]
        Mb = torch.zeros(B, n, nb, dtype=CDTYPE) if want_b else None
        u = f["u"]
        for gr in self.groups:
            ng = len(gr.lm)
            Jf = self.kin.group_jacobian(gr, u)  # (B, 3 n_g, c_g)
            Hg = H[:, :, gr.lm].reshape(B * ng, 3, 3)
            HJ = (Hg @ Jf.reshape(B * ng, 3, -1)).reshape(B, 3 * ng, -1)
            JT = Jf.transpose(1, 2)
            N.index_add_(1, gr.nflat, (JT @ HJ).reshape(B, -1))
            rhs[:, gr.cols] += (JT @ g[:, :, gr.lm].reshape(B, 3 * ng, 1))[..., 0]
            if want_b:
                Jb = f["Jb"][:, :, gr.lm].reshape(B, 3 * ng, nb)
                Mb[:, gr.cols] += HJ.transpose(1, 2) @ Jb
        out = {"N": N.view(B, n, n).to(DTYPE), "rhs": rhs.to(DTYPE)}
        if want_b:
            Jb = f["Jb"]
            HJb = (H.reshape(-1, 3, 3) @ Jb.reshape(-1, 3, nb)).reshape(P, -1, nb)
            Jb = Jb.reshape(P, -1, nb)
            out["Nbb"] = (Jb.transpose(1, 2) @ HJb).to(DTYPE)
            out["gb"] = (Jb.transpose(1, 2) @ g.reshape(P, -1, 1))[..., 0].to(DTYPE)
            out["Mb"] = Mb.to(DTYPE)
        return out

    # ---- solve -----------------------------------------------------------------------------
    def run(self, st: State, report: GNReport | None = None) -> tuple[State, torch.Tensor]:
        cfg = self.cfg
        P, T = st.transl.shape[:2]
        B = P * T
        n = self.n
        A = len(cfg.active)
        mu = torch.full((B,), cfg.mu0, dtype=DTYPE)
        mu_b = torch.full((P,), cfg.mu0, dtype=DTYPE)
        st = st.clone()
        E_cur = None
        nb = self.kin.shapedirs.shape[-1]
        par = np.asarray(self.kin.parents)[self.act.numpy()]
        for k in range(cfg.iterations):
            gamma = cfg.gamma(k)
            f = self.kin.forward(st.betas, st.rot, st.transl, jac=True, shape_jac=cfg.optimize_betas)
            Ed, H, g = self.data_terms(f["v"], gamma, jac=True)
            Ep, Nd, rp = self.prior_terms(st.rot, f["G"])
            E_cur = Ed + Ep  # (P, T)
            ne = self.normal_equations(f, H, g)
            N, rhs = ne["N"], ne["rhs"]
            idx = (3 * torch.arange(A)[:, None] + torch.arange(3)).reshape(A, 3)
            Nv = N.view(B, n, n)
            Ndf = Nd.reshape(B, A, 3, 3)
            for i in range(3):  # prior blocks on the diagonal
                for j in range(3):
                    Nv[:, idx[:, i], idx[:, j]] += Ndf[:, :, i, j]
            rhs[:, idx.reshape(-1)] += rp.reshape(B, -1)
            diag = torch.diagonal(N, dim1=1, dim2=2)
            self.last_diag = diag.reshape(P, T, n).clone()  # Gauss-Newton curvature, for preconditioning
            scale = diag.mean(1, keepdim=True).clamp(min=1e-9)
            Nd_ = N + torch.diag_embed(mu[:, None] * diag + 1e-9 * scale + 1e-12)
            Lc, info = torch.linalg.cholesky_ex(Nd_)
            bad = info > 0
            if bool(bad.any()):  # fall back to a heavily damped step where Cholesky failed
                Nd_[bad] = N[bad] + torch.diag_embed(1e3 * diag[bad] + scale[bad])
                Lc[bad] = torch.linalg.cholesky(Nd_[bad])
            if cfg.optimize_betas:
                Mb = ne["Mb"]
                Y = torch.cholesky_solve(torch.cat([rhs[..., None], Mb], -1), Lc)  # (B, n, 1 + nb)
                Yg, YM = Y[..., 0], Y[..., 1:]
                Mb_p = Mb.reshape(P, T, n, nb)
                S = (ne["Nbb"] + cfg.shape_weight * torch.eye(nb, dtype=DTYPE)
                     - torch.einsum("ptni,ptnj->pij", Mb_p, YM.reshape(P, T, n, nb)))
                rb = ne["gb"] - cfg.shape_weight * st.betas - torch.einsum("ptni,ptn->pi", Mb_p, Yg.reshape(P, T, n))
                Sd = S + torch.diag_embed(mu_b[:, None] * torch.diagonal(S, dim1=1, dim2=2) + 1e-9)
                dbeta = torch.linalg.solve(Sd, rb)
                dx = Yg - (YM @ dbeta.repeat_interleave(T, 0)[..., None])[..., 0]
            else:
                dbeta = None
                dx = torch.cholesky_solve(rhs[..., None], Lc)[..., 0]
            dx = dx.reshape(P, T, n)
            eps = dx[..., :3 * A].reshape(P, T, A, 3)
            cand = st.clone()
            Gall = torch.cat([f["G"].to(DTYPE), torch.eye(3, dtype=DTYPE).expand(P, T, 1, 3, 3)], 2)
            Gpar = Gall[:, :, torch.as_tensor(np.where(par < 0, 55, par))]
            loc = (Gpar.transpose(-1, -2) @ eps[..., None])[..., 0]
            cand.rot[:, :, self.act] = so3_exp(loc) @ st.rot[:, :, self.act]
            cand.transl = st.transl + dx[..., 3 * A:]
            if dbeta is not None:
                cand.betas = st.betas + dbeta
            E_new = self.energy(cand, gamma)
            acc = E_new <= E_cur  # (P, T)
            if dbeta is not None:
                tot_old = E_cur.sum(1) + cfg.shape_weight * (st.betas ** 2).sum(1)
                tot_new = E_new.sum(1) + cfg.shape_weight * (cand.betas ** 2).sum(1)
                ok_b = tot_new <= tot_old
                acc = acc & ok_b[:, None]
                st.betas = torch.where(ok_b[:, None], cand.betas, st.betas)
                mu_b = torch.where(ok_b, (mu_b / 3).clamp(min=1e-7), mu_b * 4)
            st.rot = torch.where(acc[..., None, None, None], cand.rot, st.rot)
            st.transl = torch.where(acc[..., None], cand.transl, st.transl)
            accf = acc.reshape(-1)
            mu = torch.where(accf, (mu / 3).clamp(min=1e-7), mu * 4)
            E_after = torch.where(acc, E_new, E_cur)
            if report is not None:
                report.energies.append(float(E_after.sum()))
                report.accepted.append(float(acc.float().mean()))
                report.iterations += 1
            rel = ((E_cur - E_after) / E_cur.clamp(min=1e-12)).max()
            if k >= cfg.iterations * 0.6 and float(rel) < cfg.tol:
                break
        return st, E_cur
