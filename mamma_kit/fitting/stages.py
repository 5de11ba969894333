"""The four-stage fit (paper: Model Fitting; supplementary: Optimization) over chunks of frames.

Per chunk (all its frames and people at once):

  init  body centres from rays, robust triangulation, Procrustes of the torso landmarks
        (and of the triangulated head and trunk keypoints)
  S1    global rotation + translation per person and frame (LM on the reprojection energy of
        the rigid torso/head landmarks; several headings where Procrustes had too little)
  S2    pose, shape and translation (LM, robust reprojection / sigma weighted by visibility,
        L2 shape prior, light pose prior on the fingers; the shape is shared by all frames
        through its Schur complement); the robust scale anneals from a fraction of the
        person's height (not of sigma) to gamma sigmas; then arms, hands and fingers are
        re-posed from their palm landmarks and neighbouring frames where that fits better,
        and S2 runs again
  S3    sigma' = sigma * clamp(e / tau, lo, 1) from the S2 reprojection errors e (tau tied to
        the image resolution) and a joint-acceleration penalty (LM, the neighbouring frames
        block-Jacobi, each person's step accepted on its whole energy)
  S4    contact: view-averaged contact probabilities pull limb landmarks onto the other body,
        repulsion pushes points out of it beyond a few mm (contact.py); LM with all people's
        steps accepted together

Keypoints (BlazePose's 33 points, when keypoints/<cam>.npz exist): a second robust term in
every stage beside the landmarks (gauss_newton.PointSet), the points regressed from the
body's vertices (body.kp_regressor), sigma = the regressor's per-point error (fraction of
the box height) x the person's size in the view, weighted by visibility x presence x
``keypoint_weight``; stage 1 uses the head and trunk points, stage 3 leaves their sigma as
it is (BlazePose's error does not shrink with the fit's agreement). Each stage's stats say
what every term contributes (energy per term before and after, at the final robust scale).

Every stage is Levenberg-Marquardt on the block-sparse problem (gauss_newton.py) rather than
the paper's L-BFGS: on a CPU it needs a few iterations where L-BFGS needs hundreds of
evaluations (FACTS.md: the official schedule would take ~10 minutes per 100 frames here).
One solver state (gauss_newton.State: local rotation matrices, translations, shapes) goes
from stage to stage, and one body forward model (kinematics.BodyKinematics) serves them all;
the pose becomes axis-angle once, when the chunks are joined into the FitResult.
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
from mamma_kit.body.rest_pose import relaxed_hand_pose
from mamma_kit.core import log
from mamma_kit.fitting import init as finit
from mamma_kit.fitting.contact import ContactConfig, ContactTerms, FloorTerms, Terms, contact_weights
from mamma_kit.fitting.data import FitData
from mamma_kit.fitting.energies import pixel_errors, pose_dict
from mamma_kit.fitting.gauss_newton import DTYPE, GaussNewton, GNConfig, GNReport, Obs, PointSet, State
from mamma_kit.fitting.kinematics import BodyKinematics, so3_exp, so3_log
from mamma_kit.fitting.projection import RigTensors
from mamma_kit.fitting.repose import FINGER_JOINTS, repose_limbs
from mamma_kit.fitting.views import set_aside_flags, set_aside_summary, spread_subset

RIGID_S1_PARTS = ("torso", "pelvis", "neck", "head")
# a view sees a person in a frame when the person's landmark visibilities there sum to more
# than this (about 4 % of the 512 landmarks: a torso or a limb, not a stray few) ...
MIN_VISIBLE_LANDMARKS = 20
# ... or (with keypoints) when this many of BlazePose's 33 points are visible (> 0.5)
MIN_VISIBLE_KEYPOINTS = 12
FOOT_PARTS = ("left_foot", "right_foot")
JOINT_BLOCK = 256  # frames posed at once for the joints written
CONSENSUS_LANDMARKS = 32  # landmarks spread over the body that judge a view's landmarks (fitting/views.py)


@dataclass
class FitConfig:
    stages: int = 4
    chunk: int = 120  # frames per chunk
    overlap: int = 16  # frames shared by neighbouring chunks
    shape_frames: int = 40  # frames spread over a long sequence to estimate the shape first
    # Geman-McClure scale in units of sigma. Lower helps the synthetic demo (stages 1-3, MPJPE at 6 / 4 / 3 /
    # 2 / 1.5: 48.4 / 46.7 / 45.7 / 44.6 / 44.3 mm; seed 7 at 4 / 3 / 2: 49.8 / 49.2 / 48.4) but not the real
    # recording's held-out views (body points at 4 / 3 / 2: 4.19 / 4.28 / 4.33 % of the box, PCK@10 86.5 /
    # 85.8 / 85.9 %): real footage decides (benchmarks/fit_sweep.py, benchmarks/heldout_view.py)
    gamma: float = 4.0
    s1_iterations: int = 6
    s2_iterations: int = 8
    s2_shape_iterations: int = 6  # stage 2 iterations that also update the shape
    s3_iterations: int = 6
    s4_iterations: int = 4
    # stage 2's robust scale starts at this fraction of the person's height in each view (px)
    # when wider than 30 sigmas, so how far a part may start from its landmarks does not
    # depend on how small their sigma is (issue 20: exact landmarks left hands 128 mm off)
    s2_wide_frac: float = 0.3
    # after stage 2, arms, hands and fingers re-posed from the palm landmarks and from
    # neighbouring frames where that fits better (repose.repose_limbs), then stage 2 again
    repose_limbs: bool = True
    repose_compare_frac: float = 0.1  # robust scale (fraction of the height, ~ a hand) judging a re-posed limb
    s2b_wide_frac: float = 0.1  # robust scale at the start of the second stage-2 pass (fraction of the height)
    tau_px_4k: float = 10.0  # tau of the sigma rescaling, px at 3840 px image width (scaled with it)
    rescale_lo: float = 0.1
    rescale_floor_frac: float = 1.0  # stage 3: rescaled sigma >= this x the median error of the body in the view
    # the joint-acceleration penalty's scale (stage 3 on): 30 (before) over-smoothed dancing arms and
    # hands. 30 -> 90 (stages 1-3): demo 43.1 -> 42.8 mm, its seed-7 render 47.5 -> 45.8; the real
    # recording's held-out views body 4.22 -> 4.18 % (PCK@10 86.5 -> 86.9), hands 2.97 -> 2.91 %
    # (PCK@5 73.8 -> 74.6); 150: 42.9 / 46.0 (benchmarks/fit_sweep.py, benchmarks/heldout_view.py)
    accel_sigma: float = 90.0  # m/s^2
    # the finger prior's sigma about the relaxed hand (below): 1.0 -> 0.5 demo 42.8 -> 42.6 mm, seed 7
    # 45.8 -> 45.5; real held-out body 4.18 -> 4.19 % (PCK@10 86.9 -> 86.8), hands 2.91 -> 2.87 %
    finger_prior_sigma: float = 0.5  # rad
    # the finger prior's mean: the relaxed hand (body.rest_pose), each joint of the four fingers flexed
    # this much (0: the flat hand); and a prior on the wrists, which had none: the network's hand
    # landmarks are about as far off as a hand is big, and unseen fingers and wrists were bent at
    # random (demo: fitted wrists 0.4-0.65 rad from straight, true 0.05). Both together, on the demo
    # (stages 1-3) 45.3 -> 43.1 mm (hands 60.0 -> 56.4); on the real recording's held-out views body
    # 4.24 -> 4.22 % / PCK@10 86.4 -> 86.5, hands 2.99 -> 2.97 % / PCK@5 73.3 -> 73.8 (benchmarks/
    # fit_sweep.py --param finger_prior_curl / wrist_prior_sigma, benchmarks/heldout_view.py)
    finger_prior_curl: float = 0.4  # rad
    wrist_prior_sigma: float = 0.5  # rad
    body_prior_sigma: float = math.inf
    min_views: int = 2  # views a frame needs to count as observed (1 with a single camera)
    floor: bool = False  # stage 4: feet above the floor z = 0, floor-contact landmarks on it
    floor_sigma: float = 0.005
    contact: ContactConfig = field(default_factory=ContactConfig)
    # BlazePose keypoints beside the landmarks (used when the data has them; 0 = off). 1 = the
    # 33 points together weigh as much as the L landmarks at equal sigma (each x L / 33): 512
    # landmarks of one network err together (a limb off as a whole) and would otherwise
    # outvote the detector. 0.1: on studio seed 3141 (4 cameras, 30 frames) 1.2 % landmarks
    # 7.3 -> 7.1 mm, 7 % / 20 % outliers 65.3 -> 37.6 mm; at 1.0 the detector's own error
    # costs good landmarks (7.3 -> 10.8 mm) (benchmarks/fit_accuracy.py --keypoints)
    keypoint_weight: float = 0.1
    # MediaPipe's hand points (keypoints/hands.py, where the hand model is sure of a hand) beside them,
    # each weighed as hand_keypoint_weight x L / 33 (as a keypoint at keypoint_weight); 0 = off. On the
    # real recording's held-out views (benchmarks/heldout_view.py) the fitted hands against the hand
    # model's points there: off 3.26 % of the box / PCK@5 69.8 %, 0.1 2.97 / 74.0, 0.3 2.90 / 73.7
    # (the body's points 4.19 / 4.19 / 4.26 %)
    hand_keypoint_weight: float = 0.1
    keypoint_min_sigma_px: float = 1.0  # a keypoint's sigma is never below this
    # the robust scale of BlazePose's 33 points, in their sigmas (the landmarks and the hand points
    # keep ``gamma``): a BlazePose point on the wrong limb or person is set aside sooner. At 2 (was 4)
    # the demo's MPJPE (stages 1-3) went 46.7 -> 45.4 mm, seed 7 49.8 -> 48.2 mm; the real recording's
    # held-out views as good as before (body 4.19 -> 4.24 % of the box, PCK@10 86.5 -> 86.4 %; hands 2.97
    # -> 2.99 %) (benchmarks/fit_sweep.py --param keypoint_gamma, benchmarks/heldout_view.py)
    keypoint_gamma: float = 2.0
    landmark_weight: float = 1.0  # 0: keypoints alone (benchmarks)
    # a view whose body keypoints miss the other views' consensus by more than this fraction of the
    # person's size there loses its keypoints for that frame, and its landmarks where they miss it
    # too (fitting/views.py; 0 = off)
    view_outlier_frac: float = 0.1

    def prior_sigma(self) -> np.ndarray:
        """(55,) rad: the pose prior's sigma per joint (the fingers' own, the rest the body's)."""
        ps = np.full(sk.NUM_JOINTS, self.body_prior_sigma)
        ps[FINGER_JOINTS] = self.finger_prior_sigma
        ps[list(finit.HAND_WRISTS)] = self.wrist_prior_sigma
        return ps


def rescale_sigma(e: torch.Tensor, w: torch.Tensor, sigma: torch.Tensor, tau: torch.Tensor | float, lo: float,
                  floor_frac: float) -> torch.Tensor:
    """Stage 3's factor on sigma (C, P, T, L) from the stage-2 pixel errors e (C, P, T, L).

    The paper's clamp(e / tau, lo, 1), with a floor on the rescaled sigma of ``floor_frac``
    times the median error of that body in that view (landmarks w > 0): a landmark may claim
    to be as precise as the fit's current agreement allows, not more. With exact landmarks
    the median error is near 0 and the paper's rescaling is left as it is; with noisy ones a
    landmark whose noise happened to be small is not trusted 10 times more than its sigma
    (stage 3 then fitted the noise: issue 20). sigma (C, P, T, L) px; 0 disables the floor."""
    scale = (e / tau).clamp(lo, 1.0)
    if floor_frac <= 0:
        return scale
    seen = w > 0
    med = torch.where(seen, e, torch.full_like(e, torch.nan)).nanmedian(-1).values.nan_to_num(0.0)  # (C, P, T)
    return torch.maximum(scale, (floor_frac * med[..., None] / sigma.clamp(min=1e-9)).clamp(max=1.0))


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

    def add_terms(self, rep: GNReport) -> None:
        """Energy per term (GaussNewton.terms) before and after the stage, summed over chunks."""
        for when, terms in (("start", rep.terms_start), ("end", rep.terms_end)):
            for k, v in terms.items():
                key = f"E_{k}_{when}"
                self.extra[key] = self.extra.get(key, 0.0) + v

    def to_dict(self) -> dict:
        extra = {k: v for k, v in self.extra.items() if not k.startswith("E_")}
        terms: dict = {}
        for k, v in self.extra.items():
            if k.startswith("E_"):
                name, when = k[2:].rsplit("_", 1)
                terms.setdefault(name, {})[when] = v
        out = {"wall_s": round(self.wall_s, 3), "cpu_s": round(self.cpu_s, 3),
               "energy_start": self.energy_start, "energy_end": self.energy_end,
               "iterations": self.iterations, **extra}
        if terms:  # what each energy contributes: its value before / after, share of the end total
            tot = sum(t.get("end", 0.0) for t in terms.values())
            for t in terms.values():
                t["share_end"] = t.get("end", 0.0) / tot if tot > 0 else 0.0
            out["energy_terms"] = terms
        return out


def record_run(stats: StageStats, rep: GNReport) -> None:
    """Add one stage's Gauss-Newton report (energies, terms, iterations) to its stats."""
    stats.add_terms(rep)
    stats.energy_start += rep.energies[0] if rep.energies else 0.0
    stats.energy_end += rep.energies[-1] if rep.energies else 0.0
    stats.iterations += rep.iterations


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
    """One chunk's fit: the final solver state, the frames observed (P, T) and the state after
    each stage (stage name -> State, the first is the stage-2 state with unobserved frames filled)."""

    state: State
    observed: np.ndarray  # (P, T)
    stats: dict[str, StageStats]
    snapshots: dict[str, State] = field(default_factory=dict)
    set_aside: tuple[np.ndarray, np.ndarray] | None = None  # the chunk's views set aside (Fitter.frames)

    @property
    def betas(self) -> np.ndarray:
        return self.state.betas.numpy().copy()  # (P, B)


def axis_angle(st: State) -> tuple[np.ndarray, np.ndarray]:
    """A state's pose as axis-angle (P, T, 55, 3) and its translation (P, T, 3), float64 arrays."""
    return so3_log(st.rot).numpy(), st.transl.numpy().copy()


def fill_unobserved(st: State, observed: np.ndarray) -> State:
    """Frames nobody saw well (observed (P, T) False): pose (as axis-angle) and translation
    interpolated per parameter from the nearest observed frames; a new state."""
    out = st.clone()
    P, T = observed.shape
    t = np.arange(T)
    for p in range(P):
        good = np.flatnonzero(observed[p])
        if len(good) == 0 or len(good) == T:
            continue
        pose = so3_log(st.rot[p]).numpy()  # (T, 55, 3)
        transl = st.transl[p].numpy().copy()  # (T, 3)
        for arr in (pose, transl):
            flat = arr.reshape(T, -1)
            for j in range(flat.shape[1]):  # per parameter column (not per landmark)
                flat[:, j] = np.interp(t, good, flat[good, j])
        bad = torch.as_tensor(~observed[p])
        out.rot[p, bad] = so3_exp(torch.as_tensor(pose[bad.numpy()], dtype=DTYPE))
        out.transl[p] = torch.as_tensor(transl, dtype=DTYPE)
    return out


def cross_fade_weights(chunks: list[tuple[int, int]], ci: int) -> np.ndarray:
    """Weights (e - s,) of chunk ci's frames: 1, ramping down where it overlaps a neighbour."""
    s, e = chunks[ci]
    w = np.ones(e - s)
    if ci > 0:
        ov = chunks[ci - 1][1] - s
        if ov > 0:
            w[:ov] = np.linspace(0, 1, ov + 2)[1:-1]
    if ci < len(chunks) - 1:
        ov = e - chunks[ci + 1][0]
        if ov > 0:
            w[-ov:] = np.linspace(1, 0, ov + 2)[1:-1]
    return w


class Fitter:
    """Fits one body model to FitData; ``fit()`` runs the chunks and joins them."""

    def __init__(self, model, data: FitData, cfg: FitConfig | None = None):
        """``data``: the take's FitData, or a FitSource whose landmarks are read a chunk at a time."""
        self.model = model
        self.cfg = cfg or FitConfig()
        self.data = data
        # views whose keypoints miss the others' consensus weigh 0 there (fitting/views.py), judged
        # frame by frame as chunks are read; the frames so far (C, P, T) for keypoints and landmarks
        lm_rest = model.v_template.numpy()[model.landmark_ids]
        self.consensus_landmarks = spread_subset(lm_rest, CONSENSUS_LANDMARKS)
        self.aside = (np.zeros(data.present.shape, bool), np.zeros(data.present.shape, bool))
        self.kin = BodyKinematics(model)
        self.cams = RigTensors.from_rig(data.rig)
        self.active_all = tuple(int(j) for j in np.unique(self.kin.infl.numpy()) if j < sk.NUM_JOINTS)
        part_ids = [sk.PART_NAMES.index(p) for p in RIGID_S1_PARTS]
        self.s1_sel = np.flatnonzero(np.isin(self.kin.part, part_ids))  # stage 1 sees these landmarks only
        self.kin_s1 = BodyKinematics(model, model.landmark_ids[self.s1_sel])
        # the pose prior of every stage: sigma per joint (55,), mean pose (55, 3) axis-angle
        self.prior = {"prior_sigma": self.cfg.prior_sigma(),
                      "prior_mean": relaxed_hand_pose(model.np.J_template, self.cfg.finger_prior_curl)}
        self.tau = torch.as_tensor([self.cfg.tau_px_4k * max(c.size) / 3840.0 for c in data.rig], dtype=torch.float32)
        self.kp = None  # keypoints: regressor and its kinematics, when the data has keypoints and they are on
        self.hands = False  # the hands' 42 points follow the 33 in the point set
        if data.has_keypoints and self.cfg.keypoint_weight > 0:
            from mamma_kit.body.kp_regressor import RIGID_POINTS, hand_regressor, keypoint_regressor, stacked

            self.body_regressor = self.regressor = keypoint_regressor(model)
            if data.has_hands and self.cfg.hand_keypoint_weight > 0:
                self.hand_regressor = hand_regressor(model)
                self.regressor = stacked(self.body_regressor, self.hand_regressor)
                self.hands = True
            self.kin_kp = BodyKinematics(model, regressor=self.regressor)
            rigid = torch.zeros(self.regressor.n_points, dtype=torch.float32)
            rigid[list(RIGID_POINTS)] = 1.0
            self.kp_rigid = rigid
            self.kp = True

    # ---- observations -------------------------------------------------------------------
    def frames(self, s) -> FitData:
        """The data of the output frames ``s`` (a slice or indices), inconsistent views set aside there;
        the flags are added to ``aside``."""
        idx = np.arange(len(self.data.frame_times))[s]
        d, flags, lm_flags = set_aside_flags(self.data.slice_frames(idx), self.cfg.view_outlier_frac,
                                             self.consensus_landmarks)
        self.note_set_aside(idx, flags, lm_flags)
        return d

    def note_set_aside(self, idx: np.ndarray, flags: np.ndarray, lm_flags: np.ndarray) -> None:
        self.aside[0][:, :, idx] |= flags
        self.aside[1][:, :, idx] |= lm_flags

    @property
    def set_aside(self) -> dict:
        """{camera: {person: {"keypoints": frames, "landmarks": frames}}} set aside in the frames read so far."""
        return set_aside_summary(self.data.cameras, self.data.person_ids, *self.aside)

    def _lm_vis(self, d: FitData) -> np.ndarray:
        return d.vis if self.cfg.landmark_weight == 1 else d.vis * np.float32(self.cfg.landmark_weight)

    def _obs(self, d: FitData) -> Obs:
        return Obs(torch.as_tensor(d.xy), torch.as_tensor(d.sigma), torch.as_tensor(self._lm_vis(d)))

    def point_xy(self, d: FitData) -> np.ndarray:
        """(C, P, T, K, 2) px the observed points: BlazePose's 33 (then the hands' 42)."""
        return np.concatenate([d.kp_xy, d.hand_xy], 3) if self.hands else d.kp_xy

    def keypoint_sigma(self, d: FitData) -> np.ndarray:
        """(C, P, T, K) px: the regressor's per-point error x the person's size in the view."""
        sig = self.regressor.sigma_frac[None, None, None, :] * d.kp_size[..., None]
        return np.maximum(sig, self.cfg.keypoint_min_sigma_px).astype(np.float32)

    def keypoint_weights(self, d: FitData) -> np.ndarray:
        """(C, P, T, K): visibility x presence x keypoint_weight x L / 33 (see FitConfig), then the
        hands' flags x hand_keypoint_weight x L / 33."""
        balance = d.shape[3] / d.kp_vis.shape[-1]
        seen = d.kp_size[..., None] > 0
        w = d.kp_vis * seen * (self.cfg.keypoint_weight * balance)
        if self.hands:
            w = np.concatenate([w, d.hand_vis * seen * (self.cfg.hand_keypoint_weight * balance)], 3)
        return w.astype(np.float32)

    def _points(self, d: FitData) -> PointSet | None:
        if self.kp is None:
            return None
        sig = torch.as_tensor(self.keypoint_sigma(d))
        groups = (("keypoints", d.kp_vis.shape[-1]), ("hand_keypoints", d.hand_vis.shape[-1])) if self.hands else None
        scale = torch.ones(self.regressor.n_points)
        scale[:d.kp_vis.shape[-1]] = self.cfg.keypoint_gamma / self.cfg.gamma
        return PointSet(self.kin_kp, Obs(torch.as_tensor(self.point_xy(d)),
                                         sig[..., None].expand(*sig.shape, 2).contiguous(),
                                         torch.as_tensor(self.keypoint_weights(d))), groups=groups, gamma_scale=scale)

    def observed(self, d: FitData) -> np.ndarray:
        """(P, T): frames that at least ``min_views`` views see the person in (see MIN_VISIBLE_*)."""
        seen = self._lm_vis(d).sum(-1) > MIN_VISIBLE_LANDMARKS  # (C, P, T)
        if self.kp is not None:  # a view with a dozen visible keypoints sees the person too
            seen |= (d.kp_vis > 0.5).sum(-1) >= MIN_VISIBLE_KEYPOINTS
        return seen.sum(0) >= min(self.cfg.min_views, len(d.rig))

    # ---- init and stage 1 ---------------------------------------------------------------
    def initial_state(self, d: FitData) -> tuple[State, dict]:
        """Rigid start per person and frame (module doc, "init"): the state (zero shape,
        rest pose, Procrustes root rotation and translation) and what init found: ``ok``
        (P, T) Procrustes succeeded, ``X`` (P, T, L, 3) triangulated landmarks, ``info``
        (P, T, L) their information, and shares for the stats."""
        C, P, T, L = d.shape
        vis = self._lm_vis(d)
        _, dirs = finit.rays(d.rig, d.xy)
        extra, kp_info = None, None
        if self.kp is None:
            centres, c_ok = finit.body_centres(d.rig, dirs, vis)
        else:  # keypoint rays place the body too (the only rays when landmarks are off)
            _, kdirs = finit.rays(d.rig, self.point_xy(d))
            kw = self.keypoint_weights(d)
            centres, c_ok = finit.body_centres(d.rig, np.concatenate([dirs, kdirs], 3), np.concatenate([vis, kw], 3))
        X, info = finit.triangulate(d.rig, dirs, d.xy, d.sigma, vis, centres)
        if self.kp is not None:  # triangulated head and trunk keypoints join the torso landmarks' Procrustes
            from mamma_kit.body.kp_regressor import RIGID_POINTS

            ksig = self.keypoint_sigma(d)
            Xk, kp_info = finit.triangulate(d.rig, kdirs, self.point_xy(d), np.repeat(ksig[..., None], 2, -1), kw, centres)
            rig_ids = list(RIGID_POINTS)
            rest_kp = self.kin_kp.rest_points(torch.zeros(1, self.kin.shapedirs.shape[-1], dtype=DTYPE))[0].numpy()
            extra = (rest_kp[rig_ids], Xk[:, :, rig_ids], kp_info[:, :, rig_ids])
        R, tr, ok = finit.rigid_from_landmarks(self.kin, X, info, centres, c_ok, extra)
        rot = torch.eye(3, dtype=DTYPE).repeat(P, T, sk.NUM_JOINTS, 1, 1)
        rot[:, :, 0] = torch.as_tensor(R)
        st = State(torch.zeros(P, self.kin.shapedirs.shape[-1], dtype=DTYPE), rot, torch.as_tensor(tr))
        out = {"procrustes_frames": float(ok.mean()), "triangulated": float((info > 0).mean()), "ok": ok,
               "X": X, "info": info}
        if kp_info is not None:
            out["keypoints_triangulated"] = float((kp_info > 0).mean())
        return st, out

    def _yaw_starts(self, obs: Obs, st: State, ok: np.ndarray, gcfg: GNConfig, n: int = 4,
                    points: PointSet | None = None) -> State:
        """Frames without a Procrustes orientation: stage 1 from ``n`` headings about the
        vertical, keeping per person and frame the one with the lowest energy."""
        frames = np.flatnonzero((~ok).any(0))
        gn = GaussNewton(self.kin_s1, self.cams, obs.frames(frames),
                         GNConfig(**{**gcfg.__dict__, "iterations": max(4, gcfg.iterations // 2)}),
                         None if points is None else points.frames(torch.as_tensor(frames)))
        best_E, best = None, None
        base = st.frames(frames)
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

    def stage_init(self, d: FitData, betas: np.ndarray | None, stats: dict) -> tuple[State, dict]:
        s0 = stats.setdefault("init", StageStats("init"))
        with _Timer(s0):
            st, info = self.initial_state(d)
            if betas is not None:
                st.betas = torch.as_tensor(betas, dtype=DTYPE)
        s0.extra.update({k: v for k, v in info.items() if k not in ("ok", "X", "info")})
        return st, info

    def stage1(self, obs: Obs, pts: PointSet | None, st: State, ok: np.ndarray, stats: dict) -> State:
        """Root rotation and translation from the rigid parts' landmarks (and keypoints)."""
        cfg = self.cfg
        s1 = stats.setdefault("stage1", StageStats("stage1"))
        with _Timer(s1):
            rep = GNReport()
            gcfg = GNConfig(active=(0,), iterations=cfg.s1_iterations, gamma_start=30.0, gamma_end=cfg.gamma)
            sel = torch.as_tensor(self.s1_sel)
            obs1 = Obs(obs.xy[..., sel, :], obs.sigma[..., sel, :], obs.w[..., sel])
            pts1 = None if pts is None else pts.with_weight(self.kp_rigid)
            if not ok.all():
                st = self._yaw_starts(obs1, st, ok, gcfg, points=pts1)
            st, _ = GaussNewton(self.kin_s1, self.cams, obs1, gcfg, pts1).run(st, rep)
            record_run(s1, rep)
        return st

    # ---- stage 2 ------------------------------------------------------------------------
    def stage2(self, obs: Obs, pts: PointSet | None, st: State, info: dict, solve_shape: bool,
               stats: dict) -> State:
        """Pose, shape (when ``solve_shape``) and translation; then limbs re-posed and again."""
        cfg = self.cfg
        s2 = stats.setdefault("stage2", StageStats("stage2"))
        with _Timer(s2):
            rep = GNReport()
            gn = GaussNewton(self.kin, self.cams, obs, GNConfig(
                active=self.active_all, iterations=cfg.s2_iterations, max_iterations=2 * cfg.s2_iterations,
                optimize_betas=solve_shape,
                betas_iterations=cfg.s2_shape_iterations, **self.prior, gamma_start=30.0,
                gamma_end=cfg.gamma, wide_frac=cfg.s2_wide_frac), pts)
            st, _ = gn.run(st, rep)
            if cfg.repose_limbs:  # limbs re-posed from their own evidence, then the joint solve again
                st, taken = repose_limbs(self.kin, self.cams, obs, st, info["X"], info["info"], cfg.gamma,
                                         cfg.repose_compare_frac, pts)
                for k, v in taken.items():
                    s2.extra[f"reposed_from_{k}"] = s2.extra.get(f"reposed_from_{k}", 0.0) + v
                gn = GaussNewton(self.kin, self.cams, obs, GNConfig(
                    active=self.active_all, iterations=cfg.s2_iterations, max_iterations=2 * cfg.s2_iterations,
                    optimize_betas=solve_shape, betas_iterations=cfg.s2_shape_iterations,
                    **self.prior, gamma_start=30.0, gamma_end=cfg.gamma,
                    wide_frac=cfg.s2b_wide_frac), pts)
                st, _ = gn.run(st, rep)
            record_run(s2, rep)
        return st

    # ---- stages 3 and 4 -----------------------------------------------------------------
    def stage3(self, d: FitData, obs: Obs, st: State, stats: dict) -> tuple[State, Obs]:
        """Sigma rescaled by stage 2's agreement, with the joint-acceleration term. Returns the
        state and the rescaled observations (stage 4 keeps them)."""
        cfg = self.cfg
        s3 = stats.setdefault("stage3", StageStats("stage3"))
        with _Timer(s3):
            # sigma rescaled by the reprojection evidence of stage 2: where a landmark already
            # agrees with the body better than tau, its sigma shrinks in proportion (down to lo)
            e, _ = pixel_errors(self.cams, obs.xy, self.kin.forward(st.betas, st.rot, st.transl).v)
            scale = rescale_sigma(e, obs.w, obs.sigma.mean(-1), self.tau.reshape(-1, 1, 1, 1), cfg.rescale_lo,
                                  cfg.rescale_floor_frac)
            obs3 = Obs(obs.xy, obs.sigma * scale[..., None].to(obs.sigma.dtype), obs.w)
            rep = GNReport()
            gn = GaussNewton(self.kin, self.cams, obs3, GNConfig(
                active=self.active_all, iterations=cfg.s3_iterations, **self.prior,
                gamma_start=cfg.gamma, gamma_end=cfg.gamma, temporal_times=d.frame_times,
                accel_sigma=cfg.accel_sigma, tol=1e-6), self._points(d))
            st, _ = gn.run(st, rep)
            record_run(s3, rep)
            s3.extra["sigma_rescaled_frac"] = s3.extra.get("sigma_rescaled_frac", 0.0) + float(
                ((scale < 1) & (obs.w > 0)).float().sum() / (obs.w > 0).float().sum().clamp(min=1))
        return st, obs3

    def _contact_terms(self, d: FitData, st: State, s4: StageStats) -> ContactTerms | None:
        """Contact terms on the frames whose people's boxes intersect (None: no such frame)."""
        T = d.shape[2]
        w_con = torch.as_tensor(contact_weights(d.contact, d.present, self.cfg.contact), dtype=torch.float32)
        ct = ContactTerms(self.model, self.cfg.contact, np.arange(T), w_con, self.active_all)
        frames = ct.contact_frames(self.kin.forward(st.betas, st.rot, st.transl), st.betas, st.transl)
        s4.extra["contact_frames"] = s4.extra.get("contact_frames", 0) + int(len(frames))
        if not len(frames):
            return None
        ct.use_frames(frames)
        return ct

    def _floor_terms(self, d: FitData) -> FloorTerms:
        cfg = self.cfg
        foot = np.flatnonzero(np.isin(self.kin.part, [sk.PART_NAMES.index(p) for p in FOOT_PARTS]))
        n = d.present.sum(0)
        pf = (d.floor * d.present[..., None]).sum(0) / np.maximum(n, 1)[..., None]
        wf = torch.as_tensor(np.clip((pf - cfg.contact.p_lo) / cfg.contact.p_span, 0, 1), dtype=torch.float32)
        return FloorTerms(self.kin, foot, wf, cfg.floor_sigma, self.active_all)

    def stage4(self, d: FitData, obs3: Obs, st: State, stats: dict) -> State:
        """Contact (contact.ContactTerms) on top of stage 3's energy, on the frames whose
        people's boxes intersect, and optionally the floor (contact.FloorTerms); Gauss-Newton
        with every person's step accepted together (contact couples them)."""
        cfg = self.cfg
        s4 = stats.setdefault("stage4", StageStats("stage4"))
        with _Timer(s4):
            ct = self._contact_terms(d, st, s4) if d.shape[1] >= 2 else None
            parts = ([ct] if ct is not None else []) + ([self._floor_terms(d)] if cfg.floor else [])
            if not parts:
                return st
            rep = GNReport()
            gn = GaussNewton(self.kin, self.cams, obs3, GNConfig(
                active=self.active_all, iterations=cfg.s4_iterations, **self.prior,
                gamma_start=cfg.gamma, gamma_end=cfg.gamma, temporal_times=d.frame_times,
                accel_sigma=cfg.accel_sigma, tol=1e-6, extra=Terms(parts), mu0=0.1, max_step=(0.05, 0.01)),
                self._points(d))
            st, _ = gn.run(st, rep)
            if ct is not None:  # penetrating points at the stage's first and final states
                if ct.inside_points_first is not None:
                    s4.extra["inside_points_start"] = s4.extra.get("inside_points_start", 0) + ct.inside_points_first
                f = self.kin.forward(st.betas, st.rot, st.transl)
                ct.refresh(f, st.betas, st.transl, force=True)
                ct.evaluate(f, st.betas, st.transl, jac=False)
                s4.extra["inside_points_end"] = s4.extra.get("inside_points_end", 0) + ct.stats["inside_points"]
            record_run(s4, rep)
            s4.extra["accepted_steps"] = s4.extra.get("accepted_steps", 0) + int(sum(a > 0 for a in rep.accepted))
        return st

    # ---- one chunk ----------------------------------------------------------------------
    def fit_chunk(self, d: FitData, betas: np.ndarray | None = None, stages: int | None = None) -> ChunkResult:
        """The stages on one chunk's frames (``betas`` (P, B): the shape, fixed; None: solved)."""
        stages = self.cfg.stages if stages is None else stages
        stats: dict[str, StageStats] = {}
        obs, pts = self._obs(d), self._points(d)
        st, info = self.stage_init(d, betas, stats)
        st = self.stage1(obs, pts, st, info["ok"], stats)
        if stages >= 2:
            st = self.stage2(obs, pts, st, info, betas is None, stats)
        observed = self.observed(d)
        st = fill_unobserved(st, observed)
        snaps = {f"stage{min(stages, 2)}": st}
        if stages >= 3 and d.shape[2] >= 3:
            st, obs3 = self.stage3(d, obs, st, stats)
            snaps["stage3"] = st
            if stages >= 4 and (d.shape[1] >= 2 or self.cfg.floor):
                st = self.stage4(d, obs3, st, stats)
                snaps["stage4"] = st
        return ChunkResult(st, observed, stats, snaps)

    # ---- whole sequence -----------------------------------------------------------------
    def plan_chunks(self, T: int) -> list[tuple[int, int]]:
        size, ov = max(self.cfg.chunk, 8), min(self.cfg.overlap, max(self.cfg.chunk // 2, 0))
        if T <= size:
            return [(0, T)]
        n = math.ceil((T - ov) / (size - ov))
        starts = np.linspace(0, T - size, n).round().astype(int)
        return [(int(s), int(s) + size) for s in starts]

    def fit(self, run_chunks=None) -> "FitResult":
        """Every chunk fitted (one shape per person: from frames spread over the sequence
        when there are several chunks), cross-faded as axis-angle where chunks overlap.
        ``run_chunks(parts, betas) -> [ChunkResult]`` fits the chunks' data (default: here, in
        order); fitting/units.py hands them to the executor."""
        chunks = self.plan_chunks(len(self.data.frame_times))
        betas, stats = self.shape_fit(chunks)
        if run_chunks is None:  # each chunk read, fitted and joined in turn: neither the take's data
            # nor every chunk's solver state is ever held at once
            results = (self.fit_chunk(self.frames(slice(s, e)), betas) for s, e in log.track(chunks, "fit chunks"))
        else:
            results = run_chunks(chunks, betas)
            for (s, e), r in zip(chunks, results):
                if r.set_aside is not None:
                    self.note_set_aside(np.arange(s, e), *r.set_aside)
        return self.join(chunks, results, betas, stats)

    def shape_fit(self, chunks: list[tuple[int, int]]) -> tuple[np.ndarray | None, dict[str, "StageStats"]]:
        """One shape per person (P, 16) from frames spread over the whole sequence when there are
        several chunks (stages 1-2), and its stats; (None, {}) for one chunk (it fits its own)."""
        stats: dict[str, StageStats] = {}
        if len(chunks) <= 1:
            return None, stats
        T = len(self.data.frame_times)
        idx = np.unique(np.linspace(0, T - 1, min(self.cfg.shape_frames, T)).round().astype(int))
        r = self.fit_chunk(self.frames(idx), None, stages=2)
        for k, st in r.stats.items():
            stats.setdefault("shape_" + k, StageStats("shape_" + k)).add(st)
        return r.betas, stats

    def join(self, chunks: list[tuple[int, int]], results, betas: np.ndarray | None,
             stats: dict[str, "StageStats"]) -> "FitResult":
        """The chunks' results (an iterable of ChunkResult, in chunk order: each is added as it comes)
        cross-faded into one FitResult (axis-angle from here on)."""
        d = self.data
        P, T = len(d.person_ids), len(d.frame_times)
        pose = np.zeros((P, T, sk.NUM_JOINTS, 3))
        transl = np.zeros((P, T, 3))
        snaps: dict[str, list] = {}
        wsum = np.zeros(T)
        observed = np.zeros((P, T), bool)
        for ci, ((s, e), r) in enumerate(zip(chunks, results)):
            if betas is None:  # one chunk: its own shape
                betas = r.betas
            w = cross_fade_weights(chunks, ci)
            for key, st in [(None, r.state), *r.snapshots.items()]:
                acc = [pose, transl] if key is None else snaps.setdefault(key, [np.zeros_like(pose),
                                                                               np.zeros_like(transl)])
                pose_c, transl_c = axis_angle(st)
                acc[0][:, s:e] += pose_c * w[None, :, None, None]
                acc[1][:, s:e] += transl_c * w[None, :, None]
            wsum[s:e] += w
            observed[:, s:e] |= r.observed
            for k, st in r.stats.items():
                stats.setdefault(k, StageStats(k)).add(st)
        pose /= wsum[None, :, None, None]
        transl /= wsum[None, :, None]
        snapshots = {k: (a[0] / wsum[None, :, None, None], a[1] / wsum[None, :, None]) for k, a in snaps.items()}
        joints = np.zeros((P, T, sk.NUM_JOINTS, 3))
        with torch.no_grad():  # a block of frames at a time: a long take's bodies are not posed at once
            for a in range(0, T, JOINT_BLOCK):
                b = min(a + JOINT_BLOCK, T)
                _, j = pose_restricted(self.model, pose_dict(torch.as_tensor(pose[:, a:b], dtype=torch.float32),
                                                             torch.as_tensor(transl[:, a:b], dtype=torch.float32),
                                                             torch.as_tensor(betas, dtype=torch.float32)))
                joints[:, a:b] = j.numpy()
        return FitResult(d.person_ids, d.frame_times, d.fps, betas, pose, transl, joints, observed, stats, chunks,
                         snapshots)


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
    snapshots: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # stage -> (pose, transl)

    def params(self, p: int, stage: str | None = None) -> dict[str, np.ndarray]:
        """SMPL-X parameter dict of person index p (T frames); ``stage`` ("stage2", ...)
        gives the parameters as they were after that stage."""
        pose, transl = (self.pose, self.transl) if stage is None else self.snapshots[stage]
        out = {}
        off = 0
        T = pose.shape[1]
        for k, n in sk.POSE_PARAMS.items():
            out[k] = pose[p, :, off // 3:(off + n) // 3].reshape(T, n)
            off += n
        out["transl"] = transl[p]
        out["betas"] = self.betas[p]
        out["expression"] = np.zeros((T, sk.NUM_EXPRESSION))
        return out
