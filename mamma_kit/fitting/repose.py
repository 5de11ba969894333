"""Arms, hands and fingers re-posed from their own evidence after a first stage 2 (issue 20).

A hand that stage 2 left in a wrong minimum (palm turned 90-180 degrees) stays there: its
landmarks are outliers to the final robust scale. Per person, frame and chain (ARM_ROOTS,
the wrists, FINGER_ROOTS: the joint and all below it) ``repose_limbs`` tries (a) the world
orientation of its triangulated palm landmarks (init.hand_orientations) with straight
fingers, (b) the chain's pose (its rotations relative to its parent) of the frames 1, 2, 4,
... away (a hand seen well in one frame is a start for its neighbours seen by one camera
only), and keeps a candidate where it lowers the chain's robust reprojection energy at a
scale of ``compare_frac`` of the person's height (at the final scale a wrong hand and a
candidate not yet refined would both be outliers).
"""

from __future__ import annotations

import numpy as np
import torch

from mamma_kit.body import skeleton as sk
from mamma_kit.fitting import init as finit
from mamma_kit.fitting.gauss_newton import DTYPE, GaussNewton, GNConfig, Obs, PointSet, State
from mamma_kit.fitting.kinematics import BodyKinematics
from mamma_kit.fitting.projection import RigTensors

# SMPL-X's finger joints (left_index1 ... right_thumb3): the only sided joints whose names
# end in their segment number
FINGER_JOINTS = np.array([j for j, n in enumerate(sk.JOINT_NAMES) if n.startswith(("left_", "right_"))
                          and n[-1] in "123"])
# chains whose pose a neighbouring frame may lend, outer to inner: the arms from the
# shoulder, the hands from the wrist, then each finger alone (a hand where one finger
# found the right bend in some frames and another in others)
ARM_ROOTS = (sk.JOINT_NAMES.index("left_shoulder"), sk.JOINT_NAMES.index("right_shoulder"))
FINGER_ROOTS = tuple(int(j) for j in FINGER_JOINTS if sk.JOINT_NAMES[j].endswith("1"))


def repose_limbs(kin: BodyKinematics, cams: RigTensors, obs: Obs, st: State, X: np.ndarray, info: np.ndarray,
                 gamma: float, compare_frac: float, points: PointSet | None = None) -> tuple[State, dict]:
    """See the module doc. kin the landmarks' kinematics, obs their observations; X (P, T,
    L, 3) triangulated landmarks with their information ``info`` (P, T, L) (init.triangulate);
    ``points`` the keypoints, whose chain points judge a chain too. Returns the state and the
    share of chains changed per kind of candidate ("palm", "neighbour")."""
    P, T = st.transl.shape[:2]
    J0, v0 = kin.rest(st.betas)
    W = kin.W.numpy()
    out = st.clone()
    taken = {"palm": 0.0, "neighbour": 0.0}
    roots = ARM_ROOTS + finit.HAND_WRISTS + FINGER_ROOTS
    # the whole body's problem, once: each chain's is its landmarks of it (GaussNewton.landmarks)
    whole = GaussNewton(kin, cams, obs, GNConfig(active=(0,), gamma_start=gamma, wide_frac=compare_frac), points)
    for w in roots:
        below = np.flatnonzero(kin.sub[w] & (np.arange(kin.J) != w))
        js = np.r_[w, below]
        chain = np.flatnonzero(kin.sub[w])
        rows = np.flatnonzero(np.isin(W.argmax(1), chain))  # the chain's landmarks
        pts = None
        if points is not None:  # the chain's keypoints (elbow, wrist, hand points) judge it too
            pts = points.with_weight(torch.as_tensor(np.isin(points.kin.W.numpy().argmax(1), chain),
                                                     dtype=torch.float32))
        gn = whole.landmarks(rows, kin.subset(rows), pts)
        e_cur = _chain_energy(gn, out)
        if w in finit.HAND_WRISTS:
            R, ok = finit.hand_orientations(v0.numpy(), J0.numpy(), X, info, finit.palm_landmarks(W, w), w)
            G = kin.forward(out.betas, out.rot, out.transl).G
            palm = out.rot[:, :, js].clone()
            palm[:, :, 0] = G[:, :, kin.parents[w]].to(DTYPE).transpose(-1, -2) @ torch.as_tensor(R, dtype=DTYPE)
            palm[:, :, 1:] = torch.eye(3, dtype=DTYPE)
            e_cur, share = _take(gn, out, js, palm, torch.as_tensor(ok), e_cur)
            taken["palm"] += share / len(finit.HAND_WRISTS)
        shift = 1
        while shift < T:
            for sgn in (1, -1):
                src = np.clip(np.arange(T) - sgn * shift, 0, T - 1)
                allowed = torch.as_tensor(np.abs(src - np.arange(T)) == shift).expand(P, T)
                e_cur, share = _take(gn, out, js, out.rot[:, src][:, :, js], allowed, e_cur)
                taken["neighbour"] += share / len(roots)
            shift *= 2
    return out, taken


def _chain_energy(gn: GaussNewton, state: State) -> torch.Tensor:
    """Per-block (P, T) robust energy of the chain's landmarks [and keypoints] at the wide
    comparison scale (gn's starting scale)."""
    f = gn.kin.forward(state.betas, state.rot, state.transl)
    e = gn.data_terms(f.v, gn.gamma0, jac=False)
    if gn.points is not None:
        e = e + gn.point_terms(gn.point_forward(f, state), gn.p_gamma0, jac=False)
    return e


def _take(gn: GaussNewton, out: State, js: np.ndarray, cand_rot: torch.Tensor, allowed: torch.Tensor,
          e_cur: torch.Tensor) -> tuple[torch.Tensor, float]:
    """Put the chain's candidate rotations cand_rot (P, T, len(js), 3, 3) into ``out`` (in
    place) where allowed (P, T) and the chain's energy drops; returns the energy (P, T) and
    the share of blocks taken."""
    cand = out.clone()
    cand.rot[:, :, js] = torch.where(allowed[..., None, None, None], cand_rot, out.rot[:, :, js])
    e_new = _chain_energy(gn, cand)
    better = allowed & (e_new < e_cur)
    out.rot[:, :, js] = torch.where(better[..., None, None, None], cand.rot[:, :, js], out.rot[:, :, js])
    return torch.where(better, e_new, e_cur), float(better.float().mean())
