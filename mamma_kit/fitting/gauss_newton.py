"""Levenberg-Marquardt on the block-sparse reprojection problem (every stage of the fit).

Unknowns: per person and frame (a block) a small world-frame rotation of every active joint
(see kinematics) and the translation; per person the shape coefficients, shared by all its
frames. The energy is the paper's robust reprojection term

    E = sum_{c,l} p_cl rho(|(mu_cl - Pi_c(V_l)) / sigma_cl|^2),  rho(s2) = g^2 s2 / (s2 + g^2)

(Geman-McClure, quadratic = Gaussian for small residuals, bounded by g^2 for outliers) plus
a light pose prior |log(R0_j^T R_j)|^2 / s_j^2 on local rotations (R0: the prior's mean pose,
the rest pose unless given) and the L2 shape prior |beta|^2.
Each iteration linearises (IRLS weights for rho), builds every block's normal matrix from
per-part dense Jacobians (a landmark only moves with the joints on its chain), eliminates
the shared shape by its Schur complement, and accepts each block's step only if the block's
energy drops (per-block damping). The scale g starts large (nearly least squares, a wide
basin from a rough start) and shrinks to its final value (graduated non-convexity).

A second point set (``PointSet``: the 33 BlazePose keypoints as regressed points, their
own kinematics riding on the landmarks' forward pass) adds the same robust term, with its
own sigma and robust scale, to every block's energy and normal equations:

    E_kp = sum_{c,k} w_ck rho(|(kp_ck - Pi_c(X_k)) / sigma_ck|^2)

Stage 3 adds the joint-acceleration term (``temporal_times``), stage 4 an extra term
(``GNConfig.extra``: contact.ContactTerms, contact.FloorTerms). ``GaussNewton.run`` is one
loop of named steps: ``linearise`` (energies and normal equations at the state),
``damped_cholesky``, ``solve_step`` (the shape by its Schur complement), ``candidate``
(the step applied to the rotations) and ``accept`` (per block, per person, or all
together). ``GaussNewton.terms(st)`` splits a state's energy into landmarks, keypoints,
prior, temporal and extra (contact) at the final robust scale: what each energy contributes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import torch

from mamma_kit.body.skeleton import NUM_JOINTS
from mamma_kit.core.reproducible import one_thread
from mamma_kit.fitting.kinematics import (CDTYPE, DTYPE, BodyKinematics, Posed, so3_exp, so3_left_jacobian_inv,
                                          so3_log)
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
class PointSet:
    """Observed points beside the landmarks: kin a BodyKinematics of regressed points,
    obs (xy, sigma (C, P, T, K, 2), w (C, P, T, K)); weight (K,) multiplies w (e.g. stage 1:
    the rigid points only); groups ((name, count), ...) names consecutive points for the
    energy report (default: all of them "keypoints"); gamma_scale (K,) multiplies the robust
    scale per point (default 1: the landmarks' gamma)."""

    kin: BodyKinematics
    obs: Obs
    weight: torch.Tensor | None = None
    groups: tuple[tuple[str, int], ...] | None = None
    gamma_scale: torch.Tensor | None = None

    def frames(self, s) -> "PointSet":
        return PointSet(self.kin, self.obs.frames(s), self.weight, self.groups, self.gamma_scale)

    def with_weight(self, weight: torch.Tensor | None) -> "PointSet":
        return PointSet(self.kin, self.obs, weight, self.groups, self.gamma_scale)


@dataclass
class State:
    """The solver state that the fit's stages pass along (float64): betas (P, B) shape per
    person, rot (P, T, 55, 3, 3) local joint rotations, transl (P, T, 3). Axis-angle is made
    from it only for the result (stages.FitResult) and the SMPL-X files."""

    betas: torch.Tensor  # (P, B)
    rot: torch.Tensor  # (P, T, 55, 3, 3)
    transl: torch.Tensor  # (P, T, 3)

    def clone(self) -> "State":
        return State(self.betas.clone(), self.rot.clone(), self.transl.clone())

    def frames(self, s) -> "State":
        """The same people over frames ``s`` (copies; the shape is shared by all frames)."""
        return State(self.betas, self.rot[:, s].clone(), self.transl[:, s].clone())


@dataclass
class GNConfig:
    active: tuple[int, ...]
    iterations: int = 12
    gamma_start: float = 30.0
    gamma_end: float = 4.0
    optimize_betas: bool = False
    shape_weight: float = 1.0
    prior_sigma: np.ndarray | None = None  # (NUM_JOINTS,) rad; inf = no prior
    prior_mean: np.ndarray | None = None  # (NUM_JOINTS, 3) axis-angle the prior pulls towards; None = rest
    landmark_weight: torch.Tensor | None = None  # (L,) multiplies visibility (stage 1: rigid parts)
    tol: float = 1e-5
    # past `iterations`, go on (at gamma_end) while some block's energy still falls by more
    # than continue_tol per iteration, up to max_iterations (None: stop at `iterations`)
    max_iterations: int | None = None
    continue_tol: float = 1e-3
    mu0: float = 1e-3
    betas_iterations: int = 1000  # shape is optimised in the first iterations only
    temporal_times: np.ndarray | None = None  # (T,) frame times: adds the joint-acceleration term
    accel_sigma: float = 30.0  # m/s^2
    extra: object | None = None  # e.g. contact.ContactTerms: refresh(f, betas, transl), evaluate(f, betas, transl, jac)
    max_step: tuple[float, float] | None = None  # per block: largest joint rotation (rad), translation (m)
    # robust scale at the first iteration as a fraction of the person's height in each view
    # (px), where that is wider than gamma_start sigmas (0: sigmas only). Tied to sigma alone,
    # the start shrinks with the landmarks' sigma: exact landmarks (sigma 0.5 px) made every
    # landmark of a hand 20 px off an outlier that pulls nothing (issue 20).
    wide_frac: float = 0.0

    def anneal(self, k: int) -> float:
        """Annealing fraction of iteration k: 0 at the start, 1 (the final scale) from 60 % of
        the iterations on."""
        if self.iterations <= 1:
            return 1.0
        return min(1.0, k / max(1, (self.iterations - 1) * 0.6))


@dataclass
class GNReport:
    energies: list[float] = field(default_factory=list)
    accepted: list[float] = field(default_factory=list)
    iterations: int = 0
    # energy per term (GaussNewton.terms) before the first and after the last run
    terms_start: dict = field(default_factory=dict)
    terms_end: dict = field(default_factory=dict)


@dataclass
class Linearisation:
    """One iteration's linearisation at a state (B = P T blocks of n columns): the forward
    pass f; the energies there, E (P, T) landmarks + keypoints + pose prior per block, Et
    (P,) temporal (None without it), Ec the extra term (0.0 without it); the normal
    equations N (B, n, n), rhs (B, n) with the prior and extra term in; and, when the shape
    is solved too, its blocks ``shape`` (GaussNewton.normal_equations's Mb, Nbb, gb)."""

    f: Posed
    E: torch.Tensor
    Et: torch.Tensor | None
    Ec: float
    N: torch.Tensor
    rhs: torch.Tensor
    shape: dict | None

    def total(self) -> float:
        return float(self.E.sum()) + (float(self.Et.sum()) if self.Et is not None else 0.0) + self.Ec


def box_heights(xy: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Height (px) of the box around each person's observed landmarks: xy (C, P, T, L, 2),
    w (C, P, T, L) -> (C, P, T) (0 where nothing is observed)."""
    y = xy[..., 1]
    seen = w > 0
    hi = torch.where(seen, y, torch.full_like(y, -torch.inf)).amax(-1)
    lo = torch.where(seen, y, torch.full_like(y, torch.inf)).amin(-1)
    return torch.where(seen.any(-1), hi - lo, torch.zeros_like(hi))


def robust(s2: torch.Tensor, gamma: float | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Geman-McClure rho(s2) and its derivative d rho / d s2 (the IRLS weight); gamma a
    scalar or a tensor broadcasting with s2."""
    g2 = gamma * gamma
    den = s2 + g2
    return g2 * s2 / den, (g2 / den) ** 2


def reprojection_terms(cams: RigTensors, xy: torch.Tensor, inv_sigma: torch.Tensor, w: torch.Tensor,
                       v: torch.Tensor, gamma: float | torch.Tensor, jac: bool):
    """Robust reprojection energy of points v (P, T, L, 3) against xy (C, P, T, L, 2) with
    1 / sigma and weights w: per-block energy (P, T) float64 [and per point H (P, T, L, 3, 3),
    g (P, T, L, 3) of the Gauss-Newton normal equations]."""
    v = v.to(CDTYPE)
    if jac:
        uv, Jp, valid = cams.project_jacobian(v[None])
    else:
        uv, valid = cams.project(v[None])
    r = (xy - uv) * inv_sigma  # (C, P, T, L, 2)
    s2 = (r * r).sum(-1)
    w = w * valid
    rho, drho = robust(s2, gamma)
    E = (w * rho).to(DTYPE).sum((0, 3))
    if not jac:
        return E
    sq = torch.sqrt(w * drho)  # (C, P, T, L)
    Jw = Jp * (inv_sigma * sq[..., None])[..., None]  # (C, P, T, L, 2, 3) whitened
    rw = r * sq[..., None]
    # per landmark H = sum_rows Jw^T Jw (3x3), g = sum_rows Jw^T r: six products summed
    # over cameras and axes (tiny batched matmuls are far slower on a CPU)
    H = torch.empty(*sq.shape[1:], 3, 3, dtype=CDTYPE)
    for i in range(3):
        for j in range(i, 3):
            H[..., i, j] = (Jw[..., i] * Jw[..., j]).sum((0, -1))
            if j != i:
                H[..., j, i] = H[..., i, j]
    g = (Jw * rw.unsqueeze(-1)).sum((0, -2))
    return E, H, g


class GaussNewton:
    def __init__(self, kin: BodyKinematics, cams: RigTensors, obs: Obs, cfg: GNConfig,
                 points: PointSet | None = None):
        self.kin, self.cams, self.obs, self.cfg = kin, cams.to(CDTYPE), obs, cfg
        self.act = torch.as_tensor(cfg.active)
        self.groups, self.n = kin.groups(cfg.active)
        w = obs.w.to(CDTYPE)
        if cfg.landmark_weight is not None:
            w = w * cfg.landmark_weight.to(CDTYPE)
        self.w = w
        self.xy = obs.xy.to(CDTYPE)
        self.inv_sigma = (1.0 / obs.sigma).to(CDTYPE)
        self.gamma0 = self._gamma_start(cfg, obs)
        self.points = points
        if points is not None:
            pw = points.obs.w.to(CDTYPE)
            if points.weight is not None:
                pw = pw * points.weight.to(CDTYPE)
            self.p_w, self.p_xy = pw, points.obs.xy.to(CDTYPE)
            self.p_inv_sigma = (1.0 / points.obs.sigma).to(CDTYPE)
            self.p_gamma_scale = 1.0 if points.gamma_scale is None else points.gamma_scale.to(CDTYPE)
            self.p_gamma0 = self._gamma_start(cfg, points.obs)
            self.p_groups, n_p = points.kin.groups(cfg.active)
            assert n_p == self.n
        ps = np.full(NUM_JOINTS, np.inf) if cfg.prior_sigma is None else np.asarray(cfg.prior_sigma, float)
        self.prior_w = torch.as_tensor(1.0 / ps[list(cfg.active)] ** 2, dtype=DTYPE)  # (A,)
        mean_j3 = np.zeros((NUM_JOINTS, 3)) if cfg.prior_mean is None else np.asarray(cfg.prior_mean, float)
        # (A, 3, 3) the transposed mean rotation of each active joint
        self.prior_R0T = so3_exp(torch.as_tensor(mean_j3[list(cfg.active)], dtype=DTYPE)).transpose(-1, -2)
        # each active joint's parent as an index into the world rotations with the identity
        # appended at index kin.J (the root's parent)
        par = np.asarray(kin.parents)[self.act.numpy()]
        self.parent_slot = torch.as_tensor(np.where(par < 0, kin.J, par))
        self.times = None if cfg.temporal_times is None else torch.as_tensor(
            np.asarray(cfg.temporal_times, float) - float(cfg.temporal_times[0]), dtype=DTYPE)

    @staticmethod
    def _gamma_start(cfg: GNConfig, obs: Obs) -> float | torch.Tensor:
        """Robust scale (in sigmas) at the first iteration: gamma_start, or per landmark
        (C, P, T, L) wide enough to span ``wide_frac`` of the person's height in that view."""
        if cfg.wide_frac <= 0:
            return float(cfg.gamma_start)
        wide_px = cfg.wide_frac * box_heights(obs.xy, obs.w)  # (C, P, T)
        sig = obs.sigma.mean(-1).clamp(min=1e-6)  # (C, P, T, L)
        return torch.clamp(wide_px[..., None] / sig, min=cfg.gamma_start).to(CDTYPE)

    def gamma_at(self, k: int) -> float | torch.Tensor:
        """Robust scale (sigmas) of iteration k: geometric from the start to gamma_end."""
        g0 = self.gamma0
        return g0 * (self.cfg.gamma_end / g0) ** self.cfg.anneal(k)

    def point_gamma_at(self, k: int) -> float | torch.Tensor:
        """The keypoints' robust scale at iteration k (their own start, same schedule)."""
        g0 = self.p_gamma0
        return g0 * (self.cfg.gamma_end / g0) ** self.cfg.anneal(k)

    # ---- energy ----------------------------------------------------------------------------
    def data_terms(self, v: torch.Tensor, gamma: float | torch.Tensor, jac: bool):
        """v (P, T, L, 3) -> per-block data energy (P, T) float64 [and H (P,T,L,3,3), g (P,T,L,3)]."""
        return reprojection_terms(self.cams, self.xy, self.inv_sigma, self.w, v, gamma, jac)

    def point_forward(self, f: Posed, st: State, jac: bool = False, shape_jac: bool = False) -> Posed:
        """The keypoints' positions (and lever arms, shape Jacobian) from the forward pass f."""
        return self.points.kin.forward_from(f, st.betas, st.transl, jac=jac, shape_jac=shape_jac)

    def point_terms(self, fp: Posed, gamma: float | torch.Tensor, jac: bool):
        """The keypoint term of ``point_forward``'s points; as data_terms."""
        return reprojection_terms(self.cams, self.p_xy, self.p_inv_sigma, self.p_w, fp.v, gamma * self.p_gamma_scale, jac)

    def prior_terms(self, rot: torch.Tensor, G: torch.Tensor | None = None):
        """Pose prior energy (P, T) [and its normal-equation diagonal blocks, rhs]; the residual
        th = log(R0^T R) of each active joint's local rotation R from the prior's mean R0."""
        th = so3_log(self.prior_R0T @ rot[:, :, self.act].to(DTYPE))  # (P, T, A, 3)
        E = ((th * th).sum(-1) * self.prior_w).sum(-1)
        if G is None:
            return E
        eye = torch.eye(3, dtype=DTYPE).expand(*G.shape[:2], 1, 3, 3)
        Gpar = torch.cat([G.to(DTYPE), eye], 2)[:, :, self.parent_slot]  # (P, T, A, 3, 3)
        # a world step eps turns R into exp(Gpar^T eps) R, so th into about th + Jl^-1(th) R0^T Gpar^T eps
        Jr = so3_left_jacobian_inv(th) @ self.prior_R0T @ Gpar.transpose(-1, -2)  # d theta / d eps (P, T, A, 3, 3)
        pw = self.prior_w[:, None, None]
        Nd = pw * (Jr.transpose(-1, -2) @ Jr)
        rhs = -(pw[..., 0] * (Jr.transpose(-1, -2) @ th[..., None])[..., 0])
        return E, Nd, rhs

    def temporal_terms(self, joints: torch.Tensor, grad: bool = False):
        """Joint-acceleration energy per person (P,) [and, per frame, the Gauss-Newton
        weight h (P, T) of each joint coordinate and right-hand side (P, T, 55, 3)]; joints
        (P, T, 55, 3).

        a_t = c- p_{t-1} + c0 p_t + c+ p_{t+1} (second divided difference on the true frame
        times), E = sum |a|^2 / s^2. Treating the neighbouring frames as fixed (block Jacobi)
        each frame sees its joints as points with weight sum c^2 / s^2."""
        t = self.times
        p = joints.to(DTYPE)
        P, T = p.shape[:2]
        if T < 3:
            z = torch.zeros(P, dtype=DTYPE)
            return (z, torch.zeros(P, T, dtype=DTYPE), torch.zeros_like(p)) if grad else z
        d1, d2, dd = t[1:-1] - t[:-2], t[2:] - t[1:-1], t[2:] - t[:-2]
        cm, cp = 2 / (d1 * dd), 2 / (d2 * dd)
        c0 = -(cm + cp)
        a = (cm[:, None, None] * p[:, :-2] + c0[:, None, None] * p[:, 1:-1] + cp[:, None, None] * p[:, 2:])
        inv = 1.0 / self.cfg.accel_sigma ** 2
        E = (a * a).sum((1, 2, 3)) * inv
        if not grad:
            return E
        h = torch.zeros(T, dtype=DTYPE)
        h[:-2] += cm ** 2
        h[1:-1] += c0 ** 2
        h[2:] += cp ** 2
        gj = torch.zeros_like(p)
        gj[:, :-2] -= cm[:, None, None] * a
        gj[:, 1:-1] -= c0[:, None, None] * a
        gj[:, 2:] -= cp[:, None, None] * a
        return E, (h * inv).expand(P, T), gj * inv

    def energy(self, st: State, gamma: float | torch.Tensor,
               point_gamma: float | torch.Tensor | None = None) -> torch.Tensor:
        """Per-block energy (P, T): landmarks at ``gamma``, keypoints at ``point_gamma``
        (default: gamma when it is a number, else the final scale), prior."""
        return self.energy_and_pass(st, gamma, point_gamma)[0]

    def energy_and_pass(self, st: State, gamma: float | torch.Tensor,
                        point_gamma: float | torch.Tensor | None = None) -> tuple[torch.Tensor, Posed]:
        """``energy`` and the forward pass it was evaluated on."""
        f = self.kin.forward(st.betas, st.rot, st.transl)
        E = self.data_terms(f.v, gamma, jac=False) + self.prior_terms(st.rot)
        if self.points is not None:
            if point_gamma is None:
                point_gamma = gamma if isinstance(gamma, (int, float)) else self.cfg.gamma_end
            E = E + self.point_terms(self.point_forward(f, st), point_gamma, jac=False)
        return E, f

    def terms(self, st: State, extra: bool = True) -> dict[str, float]:
        """The state's energy split by term at the final robust scale (see module doc);
        ``extra``: with the extra term (contact) on its current active set."""
        g = self.cfg.gamma_end
        f = self.kin.forward(st.betas, st.rot, st.transl)
        out = {"landmarks": float(self.data_terms(f.v, g, jac=False).sum()), "keypoints": 0.0}
        if self.points is not None:
            v = self.point_forward(f, st).v
            start = 0
            gs = torch.as_tensor(self.p_gamma_scale, dtype=CDTYPE).expand(v.shape[2]) * g
            for name, n in self.points.groups or (("keypoints", v.shape[2]),):
                sl = slice(start, start + n)
                out[name] = float(reprojection_terms(self.cams, self.p_xy[..., sl, :], self.p_inv_sigma[..., sl, :],
                                                     self.p_w[..., sl], v[:, :, sl], gs[sl], jac=False).sum())
                start += n
        out |= {"pose_prior": float(self.prior_terms(st.rot).sum()),
                "shape_prior": float(self.cfg.shape_weight * (st.betas ** 2).sum()) if self.cfg.optimize_betas else 0.0}
        if self.times is not None:
            out["temporal"] = float(self.temporal_terms(f.joints).sum())
        if self.cfg.extra is not None and extra:
            out["contact"] = float(self.cfg.extra.evaluate(f, st.betas, st.transl, jac=False))
        return out

    # ---- normal equations ------------------------------------------------------------------
    def normal_equations(self, f: Posed, H: torch.Tensor, g: torch.Tensor, want_b: bool = False,
                         temporal: tuple | None = None, points: tuple | None = None):
        """Normal matrices (B, n, n), right-hand sides (B, n) [and the shape blocks], float64.
        ``temporal`` = (h (P, T), g_joints (P, T, 55, 3)) adds the joints as weighted points;
        ``points`` = (fp, H, g) the keypoints' forward pass and normal-equation pieces."""
        P, T = H.shape[:2]
        B = P * T
        n = self.n
        N = torch.zeros(B, n * n, dtype=CDTYPE)
        rhs = torch.zeros(B, n, dtype=CDTYPE)
        nb = self.kin.shapedirs.shape[-1]
        Mb = torch.zeros(B, n, nb, dtype=CDTYPE) if want_b else None
        sources = [(self.kin, self.groups, f, H, g)]
        if points is not None:
            sources.append((self.points.kin, self.p_groups, *points))
        for kin, groups, fs, Hs, gs in sources:
            u = fs.u
            for gr in groups:
                ng = len(gr.lm)
                Jf = kin.group_jacobian(gr, u)  # (B, 3 n_g, c_g)
                Hg = Hs[:, :, gr.lm].reshape(B, ng, 3, 3, 1)
                Jl = Jf.view(B, ng, 3, -1)
                HJ = (Hg[:, :, :, 0] * Jl[:, :, 0:1] + Hg[:, :, :, 1] * Jl[:, :, 1:2]
                      + Hg[:, :, :, 2] * Jl[:, :, 2:3]).reshape(B, 3 * ng, -1)
                JT = Jf.transpose(1, 2)
                N.index_add_(1, gr.nflat, (JT @ HJ).reshape(B, -1))
                rhs[:, gr.cols] += (JT @ gs[:, :, gr.lm].reshape(B, 3 * ng, 1))[..., 0]
                if want_b:
                    Jb = fs.Jb[:, :, gr.lm].reshape(B, 3 * ng, nb)
                    Mb[:, gr.cols] += HJ.transpose(1, 2) @ Jb
        if temporal is not None:
            h, gj = temporal
            jg = self.kin.joint_group(self.cfg.active)
            Jj = self.kin.group_jacobian(jg, f.u_joints)  # (B, 3 NUM_JOINTS, c)
            JT = Jj.transpose(1, 2)
            N.index_add_(1, jg.nflat, ((JT @ Jj) * h.reshape(B, 1, 1).to(CDTYPE)).reshape(B, -1))
            rhs[:, jg.cols] += (JT @ gj.reshape(B, -1, 1).to(CDTYPE))[..., 0]
        out = {"N": N.view(B, n, n).to(DTYPE), "rhs": rhs.to(DTYPE)}
        if want_b:
            out["Nbb"], out["gb"] = 0.0, 0.0
            for _, _, fs, Hs, gs in sources:
                Jb = fs.Jb
                H5 = Hs.unsqueeze(-1)
                HJb = (H5[..., 0, :] * Jb[..., 0:1, :] + H5[..., 1, :] * Jb[..., 1:2, :]
                       + H5[..., 2, :] * Jb[..., 2:3, :]).reshape(P, -1, nb)
                Jb = Jb.reshape(P, -1, nb)
                out["Nbb"] = out["Nbb"] + (Jb.transpose(1, 2) @ HJb).to(DTYPE)
                out["gb"] = out["gb"] + (Jb.transpose(1, 2) @ gs.reshape(P, -1, 1))[..., 0].to(DTYPE)
            out["Mb"] = Mb.to(DTYPE)
        return out

    def add_prior_blocks(self, N: torch.Tensor, rhs: torch.Tensor, Nd: torch.Tensor, rp: torch.Tensor) -> None:
        """Add the pose prior's 3x3 blocks Nd (P, T, A, 3, 3) and rhs rp (P, T, A, 3) onto the
        joint diagonal of N (B, n, n), rhs (B, n) in place."""
        B = N.shape[0]
        A = len(self.cfg.active)
        idx = (3 * torch.arange(A)[:, None] + torch.arange(3)).reshape(A, 3)
        Ndf = Nd.reshape(B, A, 3, 3)
        for i in range(3):
            for j in range(3):
                N[:, idx[:, i], idx[:, j]] += Ndf[:, :, i, j]
        rhs[:, idx.reshape(-1)] += rp.reshape(B, -1)

    # ---- solve -----------------------------------------------------------------------------
    def linearise(self, st: State, gamma: float | torch.Tensor, point_gamma: float | torch.Tensor | None,
                  with_shape: bool) -> Linearisation:
        """Energies and normal equations at ``st`` (see Linearisation); refreshes the extra
        term's active set first."""
        P, T = st.transl.shape[:2]
        f = self.kin.forward(st.betas, st.rot, st.transl, jac=True, shape_jac=with_shape)
        Ed, H, g = self.data_terms(f.v, gamma, jac=True)
        Ep, Nd, rp = self.prior_terms(st.rot, f.G)
        E = Ed + Ep  # (P, T)
        pts = None
        if self.points is not None:
            fp = self.point_forward(f, st, jac=True, shape_jac=with_shape)
            Ek, Hk, gk = self.point_terms(fp, point_gamma, jac=True)
            E = E + Ek
            pts = (fp, Hk, gk)
        Et, tt = None, None
        if self.times is not None:
            Et, h_t, g_t = self.temporal_terms(f.joints, grad=True)
            tt = (h_t, g_t)
        ne = self.normal_equations(f, H, g, with_shape, tt, pts)
        N, rhs = ne["N"], ne["rhs"]
        self.add_prior_blocks(N, rhs, Nd, rp)
        Ec = 0.0
        extra = self.cfg.extra
        if extra is not None:
            extra.refresh(f, st.betas, st.transl)
            Ec_t, Nc, rc = extra.evaluate(f, st.betas, st.transl, jac=True)
            Ec = float(Ec_t)
            if Nc is not None:
                N = N + Nc.reshape(P * T, self.n, self.n)
                rhs = rhs + rc.reshape(P * T, self.n)
        return Linearisation(f, E, Et, Ec, N, rhs, ne if with_shape else None)

    @staticmethod
    def damped_cholesky(N: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
        """Cholesky factors (B, n, n) of N + mu diag(N) (Marquardt damping per block, mu (B,)),
        with a heavily damped fallback where the factorisation fails."""
        diag = torch.diagonal(N, dim1=1, dim2=2)
        scale = diag.mean(1, keepdim=True).clamp(min=1e-9)
        Nd_ = N + torch.diag_embed(mu[:, None] * diag + 1e-9 * scale + 1e-12)
        with one_thread():  # LAPACK's blocked factorisation sums in an order that follows its threads
            Lc, info = torch.linalg.cholesky_ex(Nd_)
            bad = info > 0
            if bool(bad.any()):
                Nd_[bad] = N[bad] + torch.diag_embed(1e3 * diag[bad] + scale[bad])
                Lc[bad] = torch.linalg.cholesky(Nd_[bad])
        return Lc

    def solve_step(self, lin: Linearisation, Lc: torch.Tensor, st: State,
                   mu_b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The step dx (P, T, n) of every block [and dbeta (P, B) of the shared shape, by its
        Schur complement with damping mu_b (P,)], clipped to ``max_step`` per block."""
        cfg = self.cfg
        P, T = st.transl.shape[:2]
        n, A = self.n, len(cfg.active)
        # the triangular solves and the shape's long contractions (over every frame and joint) on
        # one thread: their sums' order would follow the thread count
        with one_thread():
            if lin.shape is not None:
                Mb = lin.shape["Mb"]
                nb = Mb.shape[-1]
                Y = torch.cholesky_solve(torch.cat([lin.rhs[..., None], Mb], -1), Lc)  # (B, n, 1 + nb)
                Yg, YM = Y[..., 0], Y[..., 1:]
                Mb_p = Mb.reshape(P, T, n, nb)
                S = (lin.shape["Nbb"] + cfg.shape_weight * torch.eye(nb, dtype=DTYPE)
                     - torch.einsum("ptni,ptnj->pij", Mb_p, YM.reshape(P, T, n, nb)))
                rb = lin.shape["gb"] - cfg.shape_weight * st.betas - torch.einsum("ptni,ptn->pi", Mb_p, Yg.reshape(P, T, n))
                Sd = S + torch.diag_embed(mu_b[:, None] * torch.diagonal(S, dim1=1, dim2=2) + 1e-9)
                dbeta = torch.linalg.solve(Sd, rb)
                dx = Yg - (YM @ dbeta.repeat_interleave(T, 0)[..., None])[..., 0]
            else:
                dbeta = None
                dx = torch.cholesky_solve(lin.rhs[..., None], Lc)[..., 0]
        dx = dx.reshape(P, T, n)
        if cfg.max_step is not None:  # trust region: shrink a block's step to the largest allowed move
            rmax = dx[..., :3 * A].reshape(P, T, A, 3).norm(dim=-1).amax(-1) / cfg.max_step[0]
            tmax = dx[..., 3 * A:].norm(dim=-1) / cfg.max_step[1]
            dx = dx / torch.maximum(torch.maximum(rmax, tmax), torch.ones_like(rmax))[..., None]
        return dx, dbeta

    def candidate(self, st: State, f: Posed, dx: torch.Tensor, dbeta: torch.Tensor | None) -> State:
        """``st`` moved by the step: each active joint's subtree turned by its world-frame
        rotation eps (R_j <- exp([G_par^T eps_j]) R_j), translation and shape added."""
        P, T = st.transl.shape[:2]
        A = len(self.cfg.active)
        eps = dx[..., :3 * A].reshape(P, T, A, 3)
        cand = st.clone()
        Gall = torch.cat([f.G.to(DTYPE), torch.eye(3, dtype=DTYPE).expand(P, T, 1, 3, 3)], 2)
        Gpar = Gall[:, :, self.parent_slot]
        loc = (Gpar.transpose(-1, -2) @ eps[..., None])[..., 0]
        cand.rot[:, :, self.act] = so3_exp(loc) @ st.rot[:, :, self.act]
        cand.transl = st.transl + dx[..., 3 * A:]
        if dbeta is not None:
            cand.betas = st.betas + dbeta
        return cand

    def accept(self, st: State, cand: State, lin: Linearisation, gamma: float | torch.Tensor,
               point_gamma: float | torch.Tensor | None
               ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor, float]:
        """Take the candidate into ``st`` (in place) where its energy is not higher: per block;
        per person with the temporal term (it couples the frames); everyone's step together
        with an extra term (contact couples the people); the shape per person on the
        person's total. Returns the accepted blocks (P, T), the accepted shapes (P,) or
        None, the per-block energy after (P, T) and the total energy after."""
        cfg, extra = self.cfg, self.cfg.extra
        P, T = st.transl.shape[:2]
        E_cur, Et_cur, Ec_cur = lin.E, lin.Et, lin.Ec
        E_new, f_new = self.energy_and_pass(cand, gamma, point_gamma)
        acc = E_new <= E_cur  # (P, T)
        temporal = self.times is not None
        if temporal:
            Et_new = self.temporal_terms(f_new.joints)
            acc_p = (E_new.sum(1) + Et_new) <= (E_cur.sum(1) + Et_cur)
            if extra is not None:
                Ec_new = float(extra.evaluate(f_new, cand.betas, cand.transl, jac=False))
                ok_all = float(E_new.sum() + Et_new.sum()) + Ec_new <= float(E_cur.sum() + Et_cur.sum()) + Ec_cur
                acc_p = torch.full((P,), bool(ok_all))
            acc = acc_p[:, None].expand(P, T)
        ok_b = None
        if lin.shape is not None:
            tot_old = E_cur.sum(1) + cfg.shape_weight * (st.betas ** 2).sum(1)
            tot_new = E_new.sum(1) + cfg.shape_weight * (cand.betas ** 2).sum(1)
            ok_b = tot_new <= tot_old
            acc = acc & ok_b[:, None]
            st.betas = torch.where(ok_b[:, None], cand.betas, st.betas)
        st.rot = torch.where(acc[..., None, None, None], cand.rot, st.rot)
        st.transl = torch.where(acc[..., None], cand.transl, st.transl)
        E_after = torch.where(acc, E_new, E_cur)
        tot_after = float(E_after.sum())
        if temporal:
            tot_after += float(torch.where(acc_p, Et_new, Et_cur).sum())
            if extra is not None:
                tot_after += Ec_new if bool(acc_p.all()) else Ec_cur
        return acc, ok_b, E_after, tot_after

    def landmarks(self, rows: np.ndarray, kin: BodyKinematics, points: PointSet | None = None) -> "GaussNewton":
        """The same problem at landmarks ``rows`` only (``kin``: this one's kinematics at those
        points, e.g. ``self.kin.subset(rows)``), with this one's robust scales (a wide start spans
        the person's whole height, not the rows'). ``points``: this one's point set reweighted
        (PointSet.with_weight; its robust scales are this one's too), else this one's."""
        r = torch.as_tensor(rows)
        lw = self.cfg.landmark_weight
        cfg = replace(self.cfg, wide_frac=0.0, landmark_weight=None if lw is None else lw[r])
        sub = GaussNewton(kin, self.cams, Obs(self.obs.xy[..., r, :], self.obs.sigma[..., r, :], self.obs.w[..., r]),
                          cfg, self.points if points is None else points)
        sub.gamma0 = self.gamma0[..., r] if torch.is_tensor(self.gamma0) else self.gamma0
        if self.points is not None:
            sub.p_gamma0 = self.p_gamma0
        return sub

    def run(self, st: State, report: GNReport | None = None) -> tuple[State, torch.Tensor]:
        """Levenberg-Marquardt from ``st`` (not changed): per iteration linearise, factor the
        damped normal equations, solve, form the candidate and accept it where it lowers the
        energy; the robust scale anneals over the iterations (GNConfig.gamma). Returns the
        state and the per-block energy (P, T) at the last linearisation."""
        cfg = self.cfg
        P, T = st.transl.shape[:2]
        mu = torch.full((P * T,), cfg.mu0, dtype=DTYPE)  # damping per block
        mu_b = torch.full((P,), cfg.mu0, dtype=DTYPE)  # damping of each person's shape
        st = st.clone()
        E_cur = None
        if report is not None and not report.terms_start:
            report.terms_start = self.terms(st, extra=False)
        for k in range(max(cfg.iterations, cfg.max_iterations or 0)):
            gamma = self.gamma_at(k)
            pgamma = self.point_gamma_at(k) if self.points is not None else None
            lin = self.linearise(st, gamma, pgamma, cfg.optimize_betas and k < cfg.betas_iterations)
            E_cur = lin.E
            if report is not None and k == 0:
                report.energies.append(lin.total())
            dx, dbeta = self.solve_step(lin, self.damped_cholesky(lin.N, mu), st, mu_b)
            cand = self.candidate(st, lin.f, dx, dbeta)
            acc, ok_b, E_after, tot_after = self.accept(st, cand, lin, gamma, pgamma)
            mu = torch.where(acc.reshape(-1), (mu / 3).clamp(min=1e-7), mu * 4)
            if ok_b is not None:
                mu_b = torch.where(ok_b, (mu_b / 3).clamp(min=1e-7), mu_b * 4)
            if report is not None:
                report.energies.append(tot_after)
                report.accepted.append(float(acc.float().mean()))
                report.iterations += 1
            rel = float(((E_cur - E_after) / E_cur.clamp(min=1e-12)).max())
            if k >= cfg.iterations * 0.6 and rel < cfg.tol:
                break
            if k + 1 >= cfg.iterations and rel < cfg.continue_tol:
                break
        if report is not None:
            report.terms_end = self.terms(st)
        return st, E_cur
