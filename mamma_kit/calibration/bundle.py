"""Extrinsics: pose-graph initialisation and bundle adjustment over all cameras and boards.

Unknowns: per camera the intrinsics (fx, fy, cx, cy, distortion; optionally fixed) and the
pose in the frame of a reference camera (fixed: the gauge); per event the board pose. The
board's known geometry fixes the metric scale. Residuals are the reprojection errors of
every observed corner, projected by core's lens functions (see _Problem); Levenberg-Marquardt
with the board poses eliminated by the Schur complement minimises them under a robust
(soft-L1) loss, with block Jacobians by finite differences (scipy's least_squares is kept
for comparison: ``solver="scipy"``), then corners whose error exceeds five robust sigmas are
dropped and the problem is solved again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from mamma_kit.calibration.association import Event, components, consistent_poses
from mamma_kit.calibration.board import BoardSpec
from mamma_kit.calibration.intrinsics import board_pose
from mamma_kit.core.camera import Camera, nearest_rotation, rodrigues
from mamma_kit.core.lens import coefficient_names, lens_to_pixels
from mamma_kit.core.errors import UserError


# ---- pose graph ---------------------------------------------------------------------------
def _inv(R, t):
    return R.T, -R.T @ t


def event_poses(cams: dict[str, Camera], spec: BoardSpec, events: list[Event]) -> list[dict]:
    """Board -> camera pose of every (event, camera) observation; None if PnP fails."""
    out = []
    for ev in events:
        d = {}
        for c, xy in ev.obs.items():
            p = board_pose(cams[c], spec, xy)
            d[c] = None if p is None else (rodrigues(p[0]), p[1], p[2])
        out.append(d)
    return out


def _robust_mean_pose(rels: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, int]:
    members = consistent_poses(rels, np.radians(2.0), 0.03) if len(rels) > 2 else list(range(len(rels)))
    Rs = np.stack([rels[m][0] for m in members])
    ts = np.stack([rels[m][1] for m in members])
    return nearest_rotation(Rs.sum(0)), np.median(ts, 0), len(members)


def pair_graph(names: list[str], poses: list[dict]) -> dict[tuple[str, str], dict]:
    """Relative pose (camera b -> camera a) per camera pair that shares events."""
    rels: dict[tuple[str, str], list] = {}
    for d in poses:
        cs = [c for c in names if d.get(c) is not None]
        for i, a in enumerate(cs):
            for b in cs[i + 1:]:
                Ra, ta, _ = d[a]
                Rb, tb, _ = d[b]
                R = Ra @ Rb.T
                rels.setdefault((a, b), []).append((R, ta - R @ tb))
    out = {}
    for (a, b), lst in rels.items():
        R, t, n = _robust_mean_pose(lst)
        out[(a, b)] = {"R": R, "t": t, "n": len(lst), "n_agree": n}
    return out


def init_extrinsics(names: list[str], graph: dict[tuple[str, str], dict], reference: str
                    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World(=reference camera)-to-camera poses by chaining relative poses along a maximum
    spanning tree of the camera graph (edge weight = agreeing shared events)."""
    edges = sorted(graph.items(), key=lambda kv: -kv[1]["n_agree"])
    parent = {n: n for n in names}

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    tree: dict[str, list] = {n: [] for n in names}
    for (a, b), e in edges:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[ra] = rb
            tree[a].append((b, e["R"], e["t"]))  # x_a = R x_b + t
            Ri, ti = _inv(e["R"], e["t"])
            tree[b].append((a, Ri, ti))
    pose = {reference: (np.eye(3), np.zeros(3))}
    todo = [reference]
    while todo:
        a = todo.pop()
        Ra, ta = pose[a]  # x_a = Ra x_ref + ta
        for b, R_ab, t_ab in tree[a]:
            if b in pose:
                continue
            # x_a = R_ab x_b + t_ab  ->  x_b = R_ab^T (x_a - t_ab)
            Rb = R_ab.T @ Ra
            tb = R_ab.T @ (ta - t_ab)
            pose[b] = (Rb, tb)
            todo.append(b)
    return pose


# ---- bundle adjustment --------------------------------------------------------------------
@dataclass
class BundleResult:
    cameras: dict[str, Camera]  # refined, in the reference camera's frame
    event_R: np.ndarray  # (E, 3, 3) board -> reference frame
    event_t: np.ndarray  # (E, 3)
    obs_cam: np.ndarray  # (M,) camera index per observed corner (inliers and outliers)
    obs_evt: np.ndarray
    obs_corner: np.ndarray
    obs_xy: np.ndarray  # (M, 2)
    residual: np.ndarray  # (M, 2) final reprojection error (px)
    inlier: np.ndarray  # (M,) bool
    rms_px: float
    cost_history: list = field(default_factory=list)
    std: dict = field(default_factory=dict)  # per camera 1-sigma of parameters
    names: list = field(default_factory=list)
    nfev: int = 0


class _Problem:
    """The bundle's parameter vector and its vectorised projection of every observed corner.

    The projection is split in two for the finite-difference Jacobians (the intrinsics'
    columns reuse the normalised points): :meth:`normalized` (rig frame -> camera ->
    pinhole) and :meth:`pixels` (core's ``lens_to_pixels``, the lens function Camera.project
    uses, with K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]: the bundle solves no skew, and the
    cameras it returns have none). Two deliberate differences from Camera.project: a point at
    or behind a camera plane projects as if at depth 1e-9 instead of NaN (every trial step of
    Levenberg-Marquardt needs finite residuals; no such point survives at a solution), and the
    lens model is the first camera's for all (calibrate solves one model per rig).
    tests/test_projection_paths.py checks it against Camera.project for every lens model.
    ``vicon_radial`` projects too, but calibrate refuses it before it gets here (solve.py):
    its coefficients are in pixel units, where the fixed 1e-7 finite-difference steps do not
    suit them.
    """

    def __init__(self, cams: list[Camera], fix_intr: list[bool], ref: int, spec: BoardSpec, events: list[Event],
                 names: list[str]):
        self.cams = cams
        self.names = names
        self.model = cams[0].model
        self.nd = len(cams[0].dist)
        self.fix_intr = fix_intr
        self.ref = ref
        self.corners = spec.corners_b3
        C = len(cams)
        oc, oe, ok, oxy = [], [], [], []
        cam_idx = {n: k for k, n in enumerate(names)}
        for e, ev in enumerate(events):
            for c, xy in ev.obs.items():
                m = np.nonzero(np.isfinite(xy[:, 0]))[0]
                oc.append(np.full(len(m), cam_idx[c]))
                oe.append(np.full(len(m), e))
                ok.append(m)
                oxy.append(xy[m])
        self.obs_cam = np.concatenate(oc)
        self.obs_evt = np.concatenate(oe)
        self.obs_corner = np.concatenate(ok)
        self.obs_xy = np.concatenate(oxy)
        self.E = len(events)
        # parameter layout
        self.n_intr = 4 + self.nd
        off = 0
        self.intr_off = {}
        for c in range(C):
            if not fix_intr[c]:
                self.intr_off[c] = off
                off += self.n_intr
        self.extr_off = {}
        for c in range(C):
            if c != ref:
                self.extr_off[c] = off
                off += 6
        self.evt_off = off
        self.n_params = off + 6 * self.E
        self.by_cam = [np.nonzero(self.obs_cam == c)[0] for c in range(C)]
        self.active = np.ones(len(self.obs_cam), bool)

    def pack(self, cams: list[Camera], ev_R: np.ndarray, ev_t: np.ndarray) -> np.ndarray:
        x = np.zeros(self.n_params)
        for c, o in self.intr_off.items():
            K = cams[c].K
            x[o:o + self.n_intr] = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], cams[c].dist]
        for c, o in self.extr_off.items():
            x[o:o + 6] = np.r_[Rotation.from_matrix(cams[c].R).as_rotvec(), cams[c].t]
        x[self.evt_off:] = np.c_[Rotation.from_matrix(ev_R).as_rotvec(), ev_t].ravel()
        return x

    def unpack(self, x: np.ndarray):
        intr = np.zeros((len(self.cams), self.n_intr))
        R = np.zeros((len(self.cams), 3, 3))
        t = np.zeros((len(self.cams), 3))
        for c, cam in enumerate(self.cams):
            if c in self.intr_off:
                o = self.intr_off[c]
                intr[c] = x[o:o + self.n_intr]
            else:
                intr[c] = np.r_[cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], cam.dist]
            if c in self.extr_off:
                o = self.extr_off[c]
                R[c] = Rotation.from_rotvec(x[o:o + 3]).as_matrix()
                t[c] = x[o + 3:o + 6]
            else:
                R[c] = np.eye(3)
        ev = x[self.evt_off:].reshape(-1, 6)
        eR = Rotation.from_rotvec(ev[:, :3]).as_matrix() if len(ev) else np.zeros((0, 3, 3))
        return intr, R, t, eR, ev[:, 3:]

    def normalized(self, x: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Undistorted normalised image coordinates (m, 2) of the observations ``idx``."""
        _, R, t, eR, et = self.unpack(x)
        Xr_all = np.einsum("eij,kj->eki", eR, self.corners) + et[:, None, :]  # (E, N, 3) in the rig frame
        Xr = Xr_all[self.obs_evt[idx], self.obs_corner[idx]]
        oc = self.obs_cam[idx]
        xn = np.empty((len(idx), 2))
        for c in range(len(self.cams)):
            m = oc == c
            if m.any():
                Xc = Xr[m] @ R[c].T + t[c]
                z = Xc[:, 2:3]
                xn[m] = Xc[:, :2] / np.where(np.abs(z) < 1e-9, 1e-9, z)
        return xn

    def pixels(self, intr: np.ndarray, xn: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Recorded pixels (m, 2) of undistorted normalised points ``xn`` (m, 2) of the
        observations ``idx``, under the intrinsics rows ``intr`` (C, 4 + nd)."""
        oc = self.obs_cam[idx]
        out = np.empty_like(xn)
        for c in range(len(self.cams)):
            m = oc == c
            if m.any():
                p = intr[c]
                K = np.array([[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])
                out[m] = lens_to_pixels(xn[m], K, p[4:], self.model)
        return out

    def project(self, x: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
        idx = np.arange(len(self.obs_cam)) if idx is None else idx
        return self.pixels(self.unpack(x)[0], self.normalized(x, idx), idx)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        idx = np.nonzero(self.active)[0]
        return (self.project(x, idx) - self.obs_xy[idx]).ravel()

    def sparsity(self):
        """Which parameters each residual depends on (its camera's and its board's)."""
        from scipy.sparse import coo_matrix

        idx = np.nonzero(self.active)[0]
        m = 2 * len(idx)
        rows_obs = np.arange(m)
        oc = np.repeat(self.obs_cam[idx], 2)
        oe = np.repeat(self.obs_evt[idx], 2)
        rr, cc = [], []
        for c, o in self.intr_off.items():
            r = rows_obs[oc == c]
            rr.append(np.repeat(r, self.n_intr))
            cc.append(np.tile(o + np.arange(self.n_intr), len(r)))
        for c, o in self.extr_off.items():
            r = rows_obs[oc == c]
            rr.append(np.repeat(r, 6))
            cc.append(np.tile(o + np.arange(6), len(r)))
        rr.append(np.repeat(rows_obs, 6))
        cc.append((self.evt_off + 6 * oe[:, None] + np.arange(6)[None]).ravel())
        rr, cc = np.concatenate(rr), np.concatenate(cc)
        return coo_matrix((np.ones(len(rr), np.int8), (rr, cc)), shape=(m, self.n_params)).tocsr()


def bundle_adjust(cams: dict[str, Camera], fixed_intrinsics: set[str], reference: str, spec: BoardSpec,
                  events: list[Event], ev_R: np.ndarray, ev_t: np.ndarray, *, f_scale: float = 1.0,
                  outlier_sigmas: float = 5.0, rounds: int = 3, solver: str = "schur", max_iter: int = 100,
                  verbose: int = 0) -> BundleResult:
    """Robust (soft-L1) bundle adjustment with outlier rounds.

    ``solver="schur"``: Levenberg-Marquardt on the normal equations with the board poses
    eliminated by the Schur complement (the classic BA structure: each board pose touches
    only its own 6 unknowns), block Jacobians by finite differences, IRLS weights for the
    robust loss. ``solver="scipy"``: scipy.optimize.least_squares (trf, lsmr, jac_sparsity,
    loss soft_l1), kept for comparison: same optimum, but 20-100x slower here (the lsmr
    trust-region steps converge slowly on the badly scaled intrinsics)."""
    names = list(cams)
    clist = [cams[n] for n in names]
    prob = _Problem(clist, [n in fixed_intrinsics for n in names], names.index(reference), spec, events, names)
    x = prob.pack(clist, ev_R, ev_t)
    history = []
    nfev = 0
    for rnd in range(rounds):
        if solver == "scipy":
            res = least_squares(prob.residuals, x, jac_sparsity=prob.sparsity(), loss="soft_l1", f_scale=f_scale,
                                x_scale="jac", method="trf", tr_solver="lsmr",
                                tr_options={"atol": 1e-12, "btol": 1e-12}, ftol=1e-10, xtol=1e-10, gtol=1e-10,
                                max_nfev=300, verbose=verbose)
            x, n_it = res.x, res.nfev
        else:
            x, n_it = _lm_schur(prob, x, f_scale, max_iter, verbose)
        nfev += n_it
        r_all = prob.project(x) - prob.obs_xy
        norm = np.linalg.norm(r_all, axis=1)
        sigma = np.median(norm[prob.active]) / 1.1774  # median of a 2D Gaussian's norm = 1.1774 sigma
        history.append({"rms_px": float(np.sqrt(np.mean(norm[prob.active] ** 2))), "sigma_px": float(sigma),
                        "n": int(prob.active.sum()), "iterations": int(n_it)})
        new_active = norm < max(outlier_sigmas * sigma, 0.5)
        if rnd == rounds - 1 or np.array_equal(new_active, prob.active):
            break
        prob.active = new_active
    intr, R, t, eR, et = prob.unpack(x)
    out = {}
    for c, n in enumerate(names):
        p = intr[c]
        K = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
        out[n] = clist[c].copy(K=K, dist=p[4:], R=R[c], t=t[c])
    r_all = prob.project(x) - prob.obs_xy
    act = prob.active
    rms = float(np.sqrt(np.mean(np.sum(r_all[act] ** 2, 1)))) if act.any() else float("nan")
    std = _covariance_std(prob, x, names)
    return BundleResult(out, eR, et, prob.obs_cam, prob.obs_evt, prob.obs_corner, prob.obs_xy, r_all, act, rms,
                        history, std, names, nfev)


# ---- Levenberg-Marquardt with the Schur complement -----------------------------------------
def _block_jacobians(prob: "_Problem", x: np.ndarray, idx: np.ndarray):
    """Residuals (m, 2) and Jacobian blocks: camera (m, 2, pc) over [fx, fy, cx, cy,
    distortion, rvec, t] of each observation's camera, board (m, 2, 6). Finite differences,
    one vectorised evaluation per parameter index (all cameras / all boards perturbed at
    once: an observation sees only its own); intrinsics reuse the normalised points."""
    C = len(prob.cams)
    ni = prob.n_intr
    pc = ni + 6
    intr = prob.unpack(x)[0]
    xn = prob.normalized(x, idx)
    f0 = prob.pixels(intr, xn, idx)
    r = f0 - prob.obs_xy[idx]
    oc = prob.obs_cam[idx]
    Jc = np.zeros((len(idx), 2, pc))
    Je = np.zeros((len(idx), 2, 6))
    free_i = np.array([c in prob.intr_off for c in range(C)])
    fi = free_i[oc]
    # fx, fy, cx, cy: analytic
    xd = (f0 - intr[oc][:, None, 2:4].reshape(-1, 2)) / intr[oc][:, :2]
    Jc[:, 0, 0] = np.where(fi, xd[:, 0], 0.0)
    Jc[:, 1, 1] = np.where(fi, xd[:, 1], 0.0)
    Jc[:, 0, 2] = fi
    Jc[:, 1, 3] = fi
    for k in range(4, ni):
        ip = intr.copy()
        ip[:, k] += 1e-7
        Jc[:, :, k] = np.where(fi[:, None], (prob.pixels(ip, xn, idx) - f0) / 1e-7, 0.0)
    for k in range(6):
        xp = x.copy()
        moved = np.zeros(C, bool)
        for c, o in prob.extr_off.items():
            xp[o + k] += 1e-7
            moved[c] = True
        if not moved.any():
            continue
        d = (prob.pixels(intr, prob.normalized(xp, idx), idx) - f0) / 1e-7
        Jc[:, :, ni + k] = np.where(moved[oc][:, None], d, 0.0)
    for k in range(6):
        xp = x.copy()
        xp[prob.evt_off + k::6] += 1e-7
        Je[:, :, k] = (prob.pixels(intr, prob.normalized(xp, idx), idx) - f0) / 1e-7
    return r, Jc, Je


def _free_mask(prob: "_Problem") -> np.ndarray:
    """(C, pc): which camera parameters are unknowns."""
    C = len(prob.cams)
    ni = prob.n_intr
    m = np.zeros((C, ni + 6), bool)
    for c in range(C):
        m[c, :ni] = c in prob.intr_off
        m[c, ni:] = c in prob.extr_off
    return m


def _segment_sum(values: np.ndarray, keys: np.ndarray, n: int) -> np.ndarray:
    """Sum rows of ``values`` by integer key (0..n-1): sort once, np.add.reduceat."""
    order = np.argsort(keys, kind="stable")
    k = keys[order]
    out = np.zeros((n,) + values.shape[1:])
    if len(k) == 0:
        return out
    starts = np.r_[0, np.nonzero(np.diff(k))[0] + 1]
    out[k[starts]] = np.add.reduceat(values[order], starts, axis=0)
    return out


def _normal_equations(prob: "_Problem", r, Jc, Je, w, idx):
    """Blocks of J^T W J and J^T W r: U (C, pc, pc), V (E, 6, 6), W (E, C*pc, 6),
    gc (C*pc,), ge (E, 6)."""
    C, E = len(prob.cams), prob.E
    pc = Jc.shape[2]
    oc, oe = prob.obs_cam[idx], prob.obs_evt[idx]
    wJc = Jc * w[:, None, None]
    wJe = Je * w[:, None, None]
    U = _segment_sum(np.einsum("mip,miq->mpq", wJc, Jc), oc, C)
    V = _segment_sum(np.einsum("mip,miq->mpq", wJe, Je), oe, E)
    Wd = _segment_sum(np.einsum("mip,miq->mpq", wJc, Je), oe * C + oc, E * C).reshape(E, C, pc, 6)
    gc = _segment_sum(np.einsum("mip,mi->mp", wJc, r), oc, C)
    ge = _segment_sum(np.einsum("mip,mi->mp", wJe, r), oe, E)
    return U, V, Wd.reshape(E, C * pc, 6), gc.ravel(), ge


def _robust(r: np.ndarray, f_scale: float) -> tuple[np.ndarray, float]:
    """soft-L1 on each corner's 2D residual norm: IRLS weights and cost."""
    s = np.sum(r * r, 1) / (f_scale * f_scale)
    cost = float(np.sum(2.0 * (np.sqrt(1.0 + s) - 1.0)) * f_scale * f_scale)
    return 1.0 / np.sqrt(1.0 + s), cost


def _solve_schur(U, V, W, gc, ge, free, lam):
    """Damped step (cameras (C, pc), boards (E, 6)) and the camera Schur matrix."""
    C, pc = free.shape
    n = C * pc
    Ub = np.zeros((n, n))
    for c in range(C):
        Ub[c * pc:(c + 1) * pc, c * pc:(c + 1) * pc] = U[c]
    diagU = np.diag(Ub).copy()
    Ub[np.diag_indices(n)] += lam * np.maximum(diagU, 1e-9)
    dV = np.einsum("eii->ei", V)
    Vd = V + lam * np.einsum("ei,ij->eij", np.maximum(dV, 1e-12), np.eye(6))
    Vinv = np.linalg.inv(Vd)
    T = W @ Vinv  # (E, n, 6)
    E = len(V)
    S = Ub - T.transpose(1, 0, 2).reshape(n, E * 6) @ W.transpose(1, 0, 2).reshape(n, E * 6).T
    rhs = gc - np.einsum("enk,ek->n", T, ge)
    f = free.ravel()
    dc = np.zeros(n)
    if f.any():
        Sf = S[np.ix_(f, f)]
        try:
            dc[f] = -np.linalg.solve(Sf, rhs[f])
        except np.linalg.LinAlgError:
            dc[f] = -np.linalg.lstsq(Sf, rhs[f], rcond=None)[0]
    de = -np.einsum("eij,ej->ei", Vinv, ge + np.einsum("enk,n->ek", W, dc))
    return dc.reshape(C, pc), de, S


def _apply(prob: "_Problem", x, dc, de):
    xn = x.copy()
    ni = prob.n_intr
    for c in range(len(prob.cams)):
        if c in prob.intr_off:
            o = prob.intr_off[c]
            xn[o:o + ni] += dc[c, :ni]
        if c in prob.extr_off:
            o = prob.extr_off[c]
            xn[o:o + 6] += dc[c, ni:]
    xn[prob.evt_off:] += de.ravel()
    return xn


def _lm_schur(prob: "_Problem", x: np.ndarray, f_scale: float, max_iter: int, verbose: int = 0):
    idx = np.nonzero(prob.active)[0]
    free = _free_mask(prob)
    lam = 1e-3
    r, Jc, Je = _block_jacobians(prob, x, idx)
    w, cost = _robust(r, f_scale)
    it = 0
    for it in range(1, max_iter + 1):
        U, V, W, gc, ge = _normal_equations(prob, r, Jc, Je, w, idx)
        improved = False
        for _ in range(12):
            dc, de, _S = _solve_schur(U, V, W, gc, ge, free, lam)
            xn = _apply(prob, x, dc, de)
            rn = prob.project(xn, idx) - prob.obs_xy[idx]
            _, cn = _robust(rn, f_scale)
            if np.isfinite(cn) and cn < cost:
                improved = True
                break
            lam *= 10.0
        if not improved:
            break
        rel = (cost - cn) / max(cost, 1e-300)
        x, cost = xn, cn
        lam = max(lam / 5.0, 1e-9)
        if verbose:
            print(f"  LM {it}: cost {cost:.6g} lambda {lam:.1e}")
        if rel < 1e-10:
            break
        r, Jc, Je = _block_jacobians(prob, x, idx)
        w, _ = _robust(r, f_scale)
    return x, it


def _covariance_std(prob: "_Problem", x: np.ndarray, names: list[str]) -> dict:
    """1-sigma of the intrinsics, camera centre (mm) and rotation (deg) from the Gauss-Newton
    covariance sigma^2 (J^T J)^-1 at the solution, board poses marginalised by the Schur
    complement (relative to the reference camera, which is held fixed)."""
    idx = np.nonzero(prob.active)[0]
    if len(idx) == 0:
        return {}
    r, Jc, Je = _block_jacobians(prob, x, idx)
    U, V, W, gc, ge = _normal_equations(prob, r, Jc, Je, np.ones(len(idx)), idx)
    free = _free_mask(prob)
    try:
        _, _, S = _solve_schur(U, V, W, gc, ge, free, 0.0)
        f = free.ravel()
        cov = np.zeros_like(S)
        n_unknown = int(f.sum()) + 6 * prob.E
        s2 = float(np.sum(r * r)) / max(1, 2 * len(idx) - n_unknown)
        cov[np.ix_(f, f)] = np.linalg.inv(S[np.ix_(f, f)]) * s2
    except np.linalg.LinAlgError:
        return {}
    C, pc = free.shape
    ni = prob.n_intr
    dn = coefficient_names(prob.model, prob.nd)
    out = {}
    for c, name in enumerate(names):
        d = {}
        blk = cov[c * pc:(c + 1) * pc, c * pc:(c + 1) * pc]
        if c in prob.intr_off:
            sd = np.sqrt(np.clip(np.diag(blk)[:ni], 0, None))
            d.update({k: float(v) for k, v in zip(["fx", "fy", "cx", "cy"] + dn, sd)})
        if c in prob.extr_off:
            o = prob.extr_off[c]
            C6 = blk[ni:, ni:]
            q0 = x[o:o + 6]

            def centre(q):
                return -Rotation.from_rotvec(q[:3]).as_matrix().T @ q[3:]

            Jq = np.stack([(centre(q0 + 1e-7 * np.eye(6)[k]) - centre(q0)) / 1e-7 for k in range(6)], 1)
            d["center_mm"] = float(np.sqrt(max(np.trace(Jq @ C6 @ Jq.T), 0)) * 1000)
            d["rotation_deg"] = float(np.degrees(np.sqrt(max(np.trace(C6[:3, :3]), 0))))
        out[name] = d
    return out


def check_connected(names: list[str], graph: dict[tuple[str, str], dict], dets_counts: dict[str, int],
                    min_shared: int = 2, near: dict[str, str] | None = None) -> None:
    """Raise a UserError naming the cameras that share no board view with the others."""
    edges = [p for p, e in graph.items() if e["n_agree"] >= min_shared]
    comps = components(names, edges)
    if len(comps) <= 1:
        return
    main = max(comps, key=lambda c: (len(c), sum(dets_counts.get(n, 0) for n in c)))
    lonely = [c for c in comps if c is not main]
    parts = []
    for comp in lonely:
        who = ", ".join(comp)
        partner = (near or {}).get(comp[0]) or main[0]
        weak = [f"{a}-{b}: {graph[(a, b)]['n_agree']}" for (a, b) in graph
                if (a in comp) != (b in comp) and graph[(a, b)]["n_agree"] > 0]
        parts.append(f"camera{'s' if len(comp) > 1 else ''} {who} share{'s' if len(comp) == 1 else ''} no still "
                     f"board view with {', '.join(main)}" + (f" (only {', '.join(weak)})" if weak else ""))
    first = lonely[0]
    partner = (near or {}).get(first[0]) or main[0]
    raise UserError(f"the cameras are not connected: {'; '.join(parts)}",
                    f"record the board held still for a second where {first[0]} and {partner} both see it "
                    f"(a few times, at different places), then run calibrate again")
