"""The four-stage fit (paper: Model Fitting; supplementary: Optimization) over chunks of frames.

Per chunk (all its frames and people at once):

  init  body centres from rays, robust triangulation, Procrustes of the torso landmarks
  S1    global rotation + translation per person and frame (LM on the reprojection energy of
        the rigid torso/head landmarks)
  S2    pose, shape and translation (LM, robust reprojection / sigma weighted by visibility,
        L2 shape prior, light pose prior; the shape shared by all frames via its Schur complement)
  S3    sigma' = sigma * clamp(e / tau, lo, 1) from the S2 reprojection errors e (tau tied to
        the image resolution) and a joint-acceleration penalty; torch L-BFGS over the chunk
  S4    contact: view-averaged contact probabilities pull limb landmarks onto the other body,
        repulsion pushes vertices out of it beyond a few mm (contact.py); L-BFGS again

Long sequences run in overlapping chunks with one shape per person (estimated first on
frames spread over the whole sequence) and are cross-faded where chunks overlap.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from mamma_kit.body import skeleton as sk
from mamma_kit.body.lbs import pose_restricted
from mamma_kit.core import log
from mamma_kit.fitting import init as finit
from mamma_kit.fitting.contact import ContactConfig, ContactModel, contact_weights
from mamma_kit.fitting.data import FitData
from mamma_kit.fitting.energies import PoseEnergy, ReprojectionEnergy, TemporalConfig, pose_dict
from mamma_kit.fitting.gauss_newton import DTYPE, GaussNewton, GNConfig, GNReport, Obs, State
from mamma_kit.fitting.kinematics import BodyKinematics, so3_log
from mamma_kit.fitting.projection import RigTensors

RIGID_S1_PARTS = ("torso", "pelvis", "neck", "head")
FINGER_JOINTS = np.arange(25, 55)


@dataclass
class FitConfig:
    stages: int = 4
    chunk: int = 120  # frames per chunk
    overlap: int = 16  # frames shared by neighbouring chunks
    shape_frames: int = 40  # frames spread over a long sequence to estimate the shape first
    gamma: float = 4.0  # Geman-McClure scale in units of sigma
    s1_iterations: int = 8
    s2_iterations: int = 16
    s3_iterations: int = 40
    s4_iterations: int = 30
    s4_refresh: int = 10  # L-BFGS steps between contact active-set refreshes
    tau_px_4k: float = 10.0  # tau of the sigma rescaling, px at 3840 px image width (scaled with it)
    rescale_lo: float = 0.1
    accel_sigma: float = 30.0  # m/s^2
    finger_prior_sigma: float = 1.0  # rad
    body_prior_sigma: float = math.inf
    min_views: int = 2  # views a frame needs to count as observed (1 with a single camera)
    floor: bool = False  # stage 4: feet above the floor z = 0, floor-contact landmarks on it
    floor_sigma: float = 0.005
    contact: ContactConfig = field(default_factory=ContactConfig)

    def prior_sigma(self) -> np.ndarray:
        ps = np.full(sk.NUM_JOINTS, self.body_prior_sigma)
        ps[FINGER_JOINTS] = self.finger_prior_sigma
        return ps


@dataclass
class StageStats:
    name: str
    wall_s: float = 0.0
    cpu_s: float = 0.0
    energy_start: float = 0.0
    energy_end: float = 0.0
    iterations: int = 0
    extra: dict = field(default_factory=dict)

    def add(self, other: "StageStats") -> None:
        self.wall_s += other.wall_s
        self.cpu_s += other.cpu_s
        self.energy_start += other.energy_start
        self.energy_end += other.energy_end
        self.iterations += other.iterations
        for k, v in other.extra.items():
            self.extra[k] = self.extra.get(k, 0) + v if isinstance(v, (int, float)) else v

    def to_dict(self) -> dict:
        return {"wall_s": round(self.wall_s, 3), "cpu_s": round(self.cpu_s, 3),
                "energy_start": self.energy_start, "energy_end": self.energy_end,
                "iterations": self.iterations, **self.extra}


class _Timer:
    def __init__(self, stats: StageStats):
        self.stats = stats

    def __enter__(self):
        self.w, self.c = time.perf_counter(), time.process_time()
        return self.stats

    def __exit__(self, *exc):
        self.stats.wall_s += time.perf_counter() - self.w
        self.stats.cpu_s += time.process_time() - self.c


@dataclass
class ChunkResult:
    betas: np.ndarray  # (P, 16)
    pose: np.ndarray  # (P, T, 55, 3) axis-angle
    transl: np.ndarray  # (P, T, 3)
    observed: np.ndarray  # (P, T)
    stats: dict[str, StageStats]


class Fitter:
    """Fits one body model to FitData; ``fit()`` runs the chunks and joins them."""

    def __init__(self, model, data: FitData, cfg: FitConfig | None = None):
        self.model = model
        self.data = data
        self.cfg = cfg or FitConfig()
        self.kin = BodyKinematics(model)
        self.cams = RigTensors.from_rig(data.rig)
        self.active_all = tuple(int(j) for j in np.unique(self.kin.infl.numpy()) if j < sk.NUM_JOINTS)
        part_ids = [sk.PART_NAMES.index(p) for p in RIGID_S1_PARTS]
        self.s1_weight = torch.as_tensor(np.isin(self.kin.part, part_ids), dtype=torch.float32)
        w, h = data.rig[0].size
        self.tau = torch.as_tensor([self.cfg.tau_px_4k * max(c.size) / 3840.0 for c in data.rig], dtype=torch.float32)

    # ---- one chunk --------------------------------------------------------------------
    def _obs(self, d: FitData) -> Obs:
        return Obs(torch.as_tensor(d.xy), torch.as_tensor(d.sigma), torch.as_tensor(d.vis))

    def observed(self, d: FitData) -> np.ndarray:
        views = (d.vis.sum(-1) > 20).sum(0)  # (P, T)
        return views >= min(self.cfg.min_views, len(d.rig))

    def initial_state(self, d: FitData) -> tuple[State, dict]:
        C, P, T, L = d.shape
        _, dirs = finit.rays(d.rig, d.xy)
        centres, c_ok = finit.body_centres(d.rig, dirs, d.vis)
        X, info = finit.triangulate(d.rig, dirs, d.xy, d.sigma, d.vis, centres)
        R, tr, ok = finit.rigid_from_landmarks(self.kin, X, info, centres, c_ok)
        rot = torch.eye(3, dtype=DTYPE).repeat(P, T, sk.NUM_JOINTS, 1, 1)
        rot[:, :, 0] = torch.as_tensor(R)
        st = State(torch.zeros(P, self.kin.shapedirs.shape[-1], dtype=DTYPE), rot, torch.as_tensor(tr))
        return st, {"procrustes_frames": float(ok.mean()), "triangulated": float((info > 0).mean()), "ok": ok}

    def _yaw_starts(self, d: FitData, obs: Obs, st: State, ok: np.ndarray, gcfg: GNConfig, n: int = 4) -> State:
        """Frames without a Procrustes orientation: stage 1 from ``n`` headings about the
        vertical, keeping per person and frame the one with the lowest energy."""
        from mamma_kit.fitting.kinematics import so3_exp

        frames = np.flatnonzero((~ok).any(0))
        sub = Obs(obs.xy[:, :, frames], obs.sigma[:, :, frames], obs.w[:, :, frames])
        gn = GaussNewton(self.kin, self.cams, sub, GNConfig(**{**gcfg.__dict__, "iterations": max(4, gcfg.iterations // 2)}))
        best_E, best = None, None
        base = State(st.betas, st.rot[:, frames].clone(), st.transl[:, frames].clone())
        for k in range(n):
            cand = base.clone()
            Rz = so3_exp(torch.tensor([0.0, 0.0, 2 * math.pi * k / n], dtype=DTYPE))
            cand.rot[:, :, 0] = Rz @ base.rot[:, :, 0]
            res, _ = gn.run(cand)
            E = gn.energy(res, gcfg.gamma_end)
            if best_E is None:
                best_E, best = E, res
            else:
                better = E < best_E
                best.rot = torch.where(better[..., None, None, None], res.rot, best.rot)
                best.transl = torch.where(better[..., None], res.transl, best.transl)
                best_E = torch.minimum(E, best_E)
        bad = torch.as_tensor(~ok[:, frames])
        st = st.clone()
        st.rot[:, frames] = torch.where(bad[..., None, None, None], best.rot, st.rot[:, frames])
        st.transl[:, frames] = torch.where(bad[..., None], best.transl, st.transl[:, frames])
        return st

    def stage12(self, d: FitData, betas: np.ndarray | None, stats: dict, stages: int) -> tuple[State, Obs]:
        cfg = self.cfg
        obs = self._obs(d)
        s0 = stats.setdefault("init", StageStats("init"))
        with _Timer(s0):
            st, info = self.initial_state(d)
            if betas is not None:
                st.betas = torch.as_tensor(betas, dtype=DTYPE)
        s0.extra.update({k: v for k, v in info.items() if k != "ok"})
        s1 = stats.setdefault("stage1", StageStats("stage1"))
        with _Timer(s1):
            rep = GNReport()
            gcfg = GNConfig(active=(0,), iterations=cfg.s1_iterations, landmark_weight=self.s1_weight,
                            gamma_start=30.0, gamma_end=cfg.gamma)
            if not info["ok"].all():
                st = self._yaw_starts(d, obs, st, info["ok"], gcfg)
            gn = GaussNewton(self.kin, self.cams, obs, gcfg)
            st, _ = gn.run(st, rep)
            s1.energy_start += rep.energies[0] if rep.energies else 0.0
            s1.energy_end += rep.energies[-1] if rep.energies else 0.0
            s1.iterations += rep.iterations
        if stages < 2:
            return st, obs
        s2 = stats.setdefault("stage2", StageStats("stage2"))
        with _Timer(s2):
            rep = GNReport()
            gn = GaussNewton(self.kin, self.cams, obs, GNConfig(
                active=self.active_all, iterations=cfg.s2_iterations, optimize_betas=betas is None,
                prior_sigma=cfg.prior_sigma(), gamma_start=30.0, gamma_end=cfg.gamma))
            st, _ = gn.run(st, rep)
            self._curvature = gn.last_diag
            s2.energy_start += rep.energies[0] if rep.energies else 0.0
            s2.energy_end += rep.energies[-1] if rep.energies else 0.0
            s2.iterations += rep.iterations
        return st, obs

    @staticmethod
    def fill_unobserved(pose: np.ndarray, transl: np.ndarray, observed: np.ndarray) -> None:
        """Frames nobody saw well: parameters interpolated from the nearest observed frames."""
        P, T = observed.shape
        for p in range(P):
            good = np.flatnonzero(observed[p])
            if len(good) == 0 or len(good) == T:
                continue
            t = np.arange(T)
            for arr in (pose[p], transl[p]):
                flat = arr.reshape(T, -1)
                for j in range(flat.shape[1]):  # per parameter column (not per landmark)
                    flat[:, j] = np.interp(t, good, flat[good, j])

    def fit_chunk(self, d: FitData, betas: np.ndarray | None = None, stages: int | None = None) -> ChunkResult:
        cfg = self.cfg
        stages = cfg.stages if stages is None else stages
        stats: dict[str, StageStats] = {}
        st, obs = self.stage12(d, betas, stats, stages)
        pose = so3_log(st.rot).numpy()
        transl = st.transl.numpy().copy()
        observed = self.observed(d)
        self.fill_unobserved(pose, transl, observed)
        betas_out = st.betas.numpy().copy()
        if stages >= 3 and d.shape[2] >= 3:
            pose, transl = self.stage34(d, obs, pose, transl, betas_out, stats, stages)
        return ChunkResult(betas_out, pose, transl, observed, stats)

    # ---- stages 3 and 4 ----------------------------------------------------------------
    def _lbfgs(self, leaves: list[torch.Tensor], closure_energy, iterations: int) -> tuple[float, float, int]:
        opt = torch.optim.LBFGS(leaves, lr=1.0, max_iter=iterations, history_size=10,
                                line_search_fn="strong_wolfe", tolerance_grad=1e-10, tolerance_change=1e-12)
        count = [0]
        first = [None]
        last = [None]

        def closure():
            opt.zero_grad()
            E = closure_energy()
            E.backward()
            for leaf in leaves:  # index_put's backward can hand a strided gradient; L-BFGS views it flat
                if leaf.grad is not None and not leaf.grad.is_contiguous():
                    leaf.grad = leaf.grad.contiguous()
            count[0] += 1
            val = float(E.detach())
            if first[0] is None:
                first[0] = val
            last[0] = val
            return E

        opt.step(closure)
        return first[0] or 0.0, last[0] or 0.0, count[0]

    def stage34(self, d: FitData, obs: Obs, pose: np.ndarray, transl: np.ndarray, betas: np.ndarray,
                stats: dict, stages: int) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.cfg
        act = np.asarray(self.active_all)
        betas_t = torch.as_tensor(betas, dtype=torch.float32)
        pose_fixed = torch.as_tensor(pose, dtype=torch.float32)
        s3 = stats.setdefault("stage3", StageStats("stage3"))
        with _Timer(s3):
            # sigma rescaled by the reprojection evidence of stage 2
            reproj0 = ReprojectionEnergy(self.cams, obs.xy, obs.sigma, obs.w, cfg.gamma)
            with torch.no_grad():
                v0, _ = pose_restricted(self.model, pose_dict(pose_fixed, torch.as_tensor(transl, dtype=torch.float32),
                                                              betas_t))
                e, _ = reproj0.pixel_errors(v0)
            scale = (e / self.tau.reshape(-1, 1, 1, 1)).clamp(cfg.rescale_lo, 1.0)
            sigma3 = obs.sigma * scale[..., None]
            reproj = ReprojectionEnergy(self.cams, obs.xy, sigma3, obs.w, cfg.gamma)
            energy = PoseEnergy(self.model, reproj, d.frame_times, act, cfg.prior_sigma(),
                                TemporalConfig(cfg.accel_sigma))
            # L-BFGS on variables scaled by the square root of the Gauss-Newton curvature of
            # stage 2 (one scale per joint, three for the translation): the unscaled problem
            # spans ~6 orders of magnitude between the root and a fingertip
            A = len(act)
            cur = getattr(self, "_curvature", None)
            if cur is not None and cur.shape[:2] == (d.shape[1], d.shape[2]):
                hj = cur[..., :3 * A].reshape(*cur.shape[:2], A, 3).mean(-1, keepdim=True)
                ht = cur[..., 3 * A:]
            else:
                hj = torch.ones(d.shape[1], d.shape[2], A, 1, dtype=DTYPE)
                ht = torch.ones(d.shape[1], d.shape[2], 3, dtype=DTYPE)
            sj = hj.clamp(min=1e-6 * float(hj.max())).sqrt().float()
            stv = ht.clamp(min=1e-6 * float(ht.max())).sqrt().float()
            yz = (torch.as_tensor(pose[:, :, act], dtype=torch.float32) * sj).requires_grad_(True)
            yt = (torch.as_tensor(transl, dtype=torch.float32) * stv).requires_grad_(True)
            self._scales = (sj, stv)

            def total():
                terms, _, _ = energy.terms(yz / sj, pose_fixed, yt / stv, betas_t)
                return sum(terms.values())

            e0, e1, n = self._lbfgs([yz, yt], total, cfg.s3_iterations)
            s3.energy_start += e0
            s3.energy_end += e1
            s3.iterations += n
        if not (stages < 4 or d.shape[1] < 2 and not cfg.floor):
            s4 = stats.setdefault("stage4", StageStats("stage4"))
            with _Timer(s4):
                self._stage4(d, energy, yz, yt, sj, stv, pose_fixed, betas_t, s4)
        return self._merge(pose, yz.detach() / sj, act), (yt.detach() / stv).numpy()

    @staticmethod
    def _merge(pose: np.ndarray, z: torch.Tensor, act: np.ndarray) -> np.ndarray:
        out = pose.copy()
        out[:, :, act] = z.detach().numpy()
        return out

    def _stage4(self, d: FitData, energy: PoseEnergy, yz, yt, sj, stv, pose_fixed, betas_t, s4: StageStats) -> None:
        cfg = self.cfg
        cm = ContactModel(self.model, cfg.contact)
        act = energy.active
        w_con = torch.as_tensor(contact_weights(d.contact, d.present, cfg.contact), dtype=torch.float32)
        floor_w = None
        if cfg.floor:
            foot = np.isin(self.kin.part, [sk.PART_NAMES.index(p) for p in ("left_foot", "right_foot")])
            n = d.present.sum(0)
            pf = (d.floor * d.present[..., None]).sum(0) / np.maximum(n, 1)[..., None]
            floor_w = (torch.as_tensor(foot), torch.as_tensor(np.clip((pf - 0.2) / 0.4, 0, 1), dtype=torch.float32))

        def posed_proxy(frames):
            pose = pose_fixed.clone()
            pose[:, :, act] = yz / sj
            prm = pose_dict(pose[:, frames], (yt / stv)[:, frames], betas_t)
            v, _ = pose_restricted(self.model, prm, cm.proxy_ids)
            return v

        with torch.no_grad():
            gate = cm.gate(posed_proxy(slice(None)), margin=cfg.contact.margin) if d.shape[1] >= 2 else \
                np.zeros(d.shape[2], bool)
        frames = torch.as_tensor(np.flatnonzero(gate))
        s4.extra["contact_frames"] = s4.extra.get("contact_frames", 0) + int(len(frames))
        if len(frames) == 0 and floor_w is None:
            return
        remaining = cfg.s4_iterations
        first = None
        last = None
        while remaining > 0:
            with torch.no_grad():
                sets = []
                if len(frames):
                    pv = posed_proxy(frames)
                    pose = pose_fixed.clone()
                    pose[:, :, act] = yz / sj
                    lm, _ = pose_restricted(self.model, pose_dict(pose[:, frames], (yt / stv)[:, frames], betas_t))
                    sets = cm.refresh(pv, lm, w_con[:, frames])
                if first is None and len(frames):
                    c0 = cm.energy(sets, pv, lm)
                    s4.extra["inside_points_start"] = s4.extra.get("inside_points_start", 0) + c0["inside_points"]

            def total():
                terms, v, _ = energy.terms(yz / sj, pose_fixed, yt / stv, betas_t)
                E = sum(terms.values())
                if len(frames):
                    pv_g = posed_proxy(frames)
                    c = cm.energy(sets, pv_g, v[:, frames])
                    E = E + c["repulsion"] + c["contact"]
                if floor_w is not None:
                    foot, fw = floor_w
                    zf = v[:, :, foot, 2]
                    E = E + ((torch.relu(-zf) ** 2).sum(dtype=torch.float64)
                             + (fw[:, :, foot] * zf ** 2).sum(dtype=torch.float64)) / cfg.floor_sigma ** 2
                return E

            n = min(cfg.s4_refresh, remaining)
            e0, e1, k = self._lbfgs([yz, yt], total, n)
            first = e0 if first is None else first
            last = e1
            s4.iterations += k
            remaining -= n
        s4.energy_start += first or 0.0
        s4.energy_end += last or 0.0
        if len(frames):
            with torch.no_grad():
                pv = posed_proxy(frames)
                pose = pose_fixed.clone()
                pose[:, :, act] = yz / sj
                lm, _ = pose_restricted(self.model, pose_dict(pose[:, frames], (yt / stv)[:, frames], betas_t))
                c1 = cm.energy(cm.refresh(pv, lm, w_con[:, frames]), pv, lm)
            s4.extra["inside_points_end"] = s4.extra.get("inside_points_end", 0) + c1["inside_points"]

    # ---- whole sequence ---------------------------------------------------------------
    def plan_chunks(self, T: int) -> list[tuple[int, int]]:
        size, ov = max(self.cfg.chunk, 8), min(self.cfg.overlap, max(self.cfg.chunk // 2, 0))
        if T <= size:
            return [(0, T)]
        n = math.ceil((T - ov) / (size - ov))
        starts = np.linspace(0, T - size, n).round().astype(int)
        return [(int(s), int(s) + size) for s in starts]

    def fit(self) -> "FitResult":
        d = self.data
        C, P, T, L = d.shape
        chunks = self.plan_chunks(T)
        stats: dict[str, StageStats] = {}
        betas = None
        if len(chunks) > 1:  # one shape per person, from frames spread over the whole sequence
            idx = np.unique(np.linspace(0, T - 1, min(self.cfg.shape_frames, T)).round().astype(int))
            r = self.fit_chunk(d.slice_frames(idx), None, stages=2)
            betas = r.betas
            for k, s in r.stats.items():
                stats.setdefault("shape_" + k, StageStats("shape_" + k)).add(s)
        pose = np.zeros((P, T, sk.NUM_JOINTS, 3))
        transl = np.zeros((P, T, 3))
        wsum = np.zeros(T)
        observed = np.zeros((P, T), bool)
        for ci, (s, e) in enumerate(log.track(chunks, "fit chunks")):
            r = self.fit_chunk(d.slice_frames(slice(s, e)), betas)
            if betas is None:
                betas = r.betas
            w = np.ones(e - s)
            if ci > 0:  # cross-fade with the previous chunk where they overlap
                ov = chunks[ci - 1][1] - s
                if ov > 0:
                    w[:ov] = np.linspace(0, 1, ov + 2)[1:-1]
            if ci < len(chunks) - 1:
                ov = e - chunks[ci + 1][0]
                if ov > 0:
                    w[-ov:] = np.linspace(1, 0, ov + 2)[1:-1]
            pose[:, s:e] += r.pose * w[None, :, None, None]
            transl[:, s:e] += r.transl * w[None, :, None]
            wsum[s:e] += w
            observed[:, s:e] |= r.observed
            for k, st in r.stats.items():
                stats.setdefault(k, StageStats(k)).add(st)
        pose /= wsum[None, :, None, None]
        transl /= wsum[None, :, None]
        with torch.no_grad():
            _, joints = pose_restricted(self.model, pose_dict(torch.as_tensor(pose, dtype=torch.float32),
                                                              torch.as_tensor(transl, dtype=torch.float32),
                                                              torch.as_tensor(betas, dtype=torch.float32)))
        return FitResult(d.person_ids, d.frame_times, d.fps, betas, pose, transl, joints.numpy().astype(np.float64),
                         observed, stats, chunks)


@dataclass
class FitResult:
    person_ids: list[int]
    frame_times: np.ndarray
    fps: float
    betas: np.ndarray  # (P, 16)
    pose: np.ndarray  # (P, T, 55, 3)
    transl: np.ndarray  # (P, T, 3)
    joints: np.ndarray  # (P, T, 55, 3)
    observed: np.ndarray  # (P, T)
    stats: dict[str, StageStats]
    chunks: list[tuple[int, int]]

    def params(self, p: int) -> dict[str, np.ndarray]:
        """SMPL-X parameter dict of person index p (T frames)."""
        out = {}
        off = 0
        T = self.pose.shape[1]
        for k, n in sk.POSE_PARAMS.items():
            out[k] = self.pose[p, :, off // 3:(off + n) // 3].reshape(T, n)
            off += n
        out["transl"] = self.transl[p]
        out["betas"] = self.betas[p]
        out["expression"] = np.zeros((T, sk.NUM_EXPRESSION))
        return out
