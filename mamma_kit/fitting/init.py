"""Initialisation without any regressor: rays, triangulated landmarks, a rigid placement.

- ``body_centres``: per person and frame, the 3D point closest to the rays through all its
  landmarks in all views (the paper's initialisation).
- ``triangulate``: every landmark by weighted ray intersection (a 3x3 solve each), each
  ray weighted by visibility / (sigma in metres at the body's depth)^2, refined by
  reweighting rounds on the reprojection error (Geman-McClure, shrinking scale) so
  outliers lose their say.
- ``rigid_from_landmarks``: global rotation and translation per person and frame by a
  weighted Procrustes (Kabsch) fit of the rest-pose torso landmarks (and, with keypoints,
  the triangulated head and trunk points) to their triangulated positions: orientation
  comes straight from the landmark set; only frames where too little was triangulated get
  stage 1 from several headings (stages.Fitter._yaw_starts).
- ``palm_landmarks`` / ``hand_orientations``: each hand's world orientation from its
  triangulated palm landmarks (the palm candidate of repose.repose_limbs).
"""

from __future__ import annotations

import numpy as np
import torch

from mamma_kit.body import skeleton as sk
from mamma_kit.core.camera import Rig

RIGID_PARTS = ("torso", "pelvis")


def rays(rig: Rig, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (C, ..., 2) -> camera centres (C, 3) and unit world ray directions (C, ..., 3)."""
    centres = rig.centers()
    dirs = np.stack([cam.ray(xy[i].reshape(-1, 2).astype(np.float64))[1].reshape(*xy.shape[1:-1], 3)
                     for i, cam in enumerate(rig)])
    return centres, dirs


def solve_rays(centres: np.ndarray, dirs: np.ndarray, w: np.ndarray, axis: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares point of weighted rays, summing over ``axis``; returns X and the 3x3 A."""
    I = np.eye(3)
    Pm = I - dirs[..., :, None] * dirs[..., None, :]  # (..., 3, 3) projector orthogonal to the ray
    cshape = (centres.shape[0],) + (1,) * (dirs.ndim - 2) + (3,)
    C = centres.reshape(cshape)
    A = (w[..., None, None] * Pm).sum(axis)
    b = (w[..., None] * (Pm @ C[..., None])[..., 0]).sum(axis)
    # regularise relative to each system's scale: weights span many decades (1 / sigma_m^2)
    tr = np.trace(A, axis1=-2, axis2=-1)[..., None, None]
    A_reg = A + (1e-9 * tr + 1e-12) * I
    X = np.linalg.solve(A_reg, b[..., None])[..., 0]
    return X, A


def body_centres(rig: Rig, dirs: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """dirs (C, P, T, L, 3), w (C, P, T, L) -> centres (P, T, 3), ok (P, T) (rays from >= 2 views)."""
    X, A = solve_rays(rig.centers(), dirs, w, axis=(0, 3))
    views = ((w > 0).sum(3) > 0).sum(0)
    return X, views >= 2


def triangulate(rig: Rig, dirs: np.ndarray, xy: np.ndarray, sigma: np.ndarray, w: np.ndarray,
                centres_pt3: np.ndarray, gammas: tuple[float, ...] = (30.0, 10.0, 3.0)) -> tuple[np.ndarray, np.ndarray]:
    """Robust weighted triangulation of every landmark.

    dirs (C, P, T, L, 3), xy/sigma (C, P, T, L, 2), w (C, P, T, L) visibility weights,
    centres (P, T, 3) body centres (for each view's metres-per-pixel). Reweighting rounds
    use Geman-McClure scales ``gammas`` (in sigmas), shrinking so that a ray far off at the
    start does not take the others with it. Returns X (P, T, L, 3) and an information weight
    (P, T, L) (1 / m^2 along the worst direction; 0 = unknown).
    """
    C = len(rig)
    cc = rig.centers()
    f = np.array([0.5 * (c.K[0, 0] + c.K[1, 1]) for c in rig])
    depth = np.linalg.norm(centres_pt3[None] - cc[:, None, None], axis=-1)  # (C, P, T)
    sig_px = np.maximum(np.sqrt(0.5 * (sigma ** 2).sum(-1)), 0.1)  # (C, P, T, L); no ray is exact
    sig_m = sig_px * (depth / f[:, None, None])[..., None]
    base = w / np.maximum(sig_m, 1e-6) ** 2
    wr = base.copy()
    X = None
    for r in range(len(gammas) + 1):
        X, A = solve_rays(cc, dirs, wr, axis=0)
        if r == len(gammas):
            break
        gamma = gammas[r]
        proj = np.stack([cam.project(X) for cam in rig])  # (C, P, T, L, 2)
        s2 = (((proj - xy) / np.maximum(sigma, 1e-6)) ** 2).sum(-1)
        s2 = np.where(np.isfinite(s2), s2, 1e12)
        wr = base * (gamma ** 2 / (s2 + gamma ** 2)) ** 2
    ev = np.linalg.eigvalsh(A)  # ascending
    n_views = (wr > 1e-3 * np.maximum(base.max(0, keepdims=True), 1e-30)).sum(0) if C else 0
    ok = (ev[..., 0] > 1e-3 * np.maximum(ev[..., 2], 1e-30)) & (n_views >= 2) & np.isfinite(X).all(-1)
    info = np.where(ok, ev[..., 0], 0.0)
    return np.where(ok[..., None], X, 0.0), info


def kabsch(Y: np.ndarray, X: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted rigid fit X ~ R Y + c per batch: Y (..., n, 3) or (n, 3), X (..., n, 3), w (..., n).
    Returns R (..., 3, 3), c (..., 3) and ok (...) (enough spread weight)."""
    ws = w.sum(-1, keepdims=True)
    ok = (w > 0).sum(-1) >= 6
    wn = w / np.maximum(ws, 1e-30)
    Yb = np.broadcast_to(Y, X.shape)
    my = (wn[..., None] * Yb).sum(-2)
    mx = (wn[..., None] * X).sum(-2)
    S = np.einsum("...n,...ni,...nj->...ij", wn, X - mx[..., None, :], Yb - my[..., None, :])
    U, _, Vt = np.linalg.svd(S)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros(S.shape)
    D[..., 0, 0] = 1
    D[..., 1, 1] = 1
    D[..., 2, 2] = d
    R = U @ D @ Vt
    c = mx - (R @ my[..., None])[..., 0]
    return R, c, ok


def rigid_from_landmarks(kin, X: np.ndarray, info: np.ndarray, centres: np.ndarray,
                         centre_ok: np.ndarray, extra: tuple | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Root rotation (P, T, 3, 3) and transl (P, T, 3) from triangulated landmarks
    (P, T, L, 3) with the rest pose at zero shape; frames without enough torso landmarks
    take the nearest good frame's rotation and the body centre. Returns also ok (P, T).
    ``extra`` = (rest points (n, 3), triangulated (P, T, n, 3), information (P, T, n)):
    more rigid points in the same Procrustes (the head and trunk keypoints)."""
    P, T = X.shape[:2]
    J0, v0 = kin.rest(torch.zeros(1, kin.shapedirs.shape[-1], dtype=kin.v_template.dtype))
    J0, v0 = J0[0].numpy(), v0[0].numpy()
    part_ids = [sk.PART_NAMES.index(p) for p in RIGID_PARTS]
    sel = np.isin(kin.part, part_ids)
    Y, Xs, ws = v0[sel], X[:, :, sel], info[:, :, sel]
    if extra is not None:
        Y = np.concatenate([Y, extra[0]], 0)
        Xs = np.concatenate([Xs, extra[1]], 2)
        ws = np.concatenate([ws, extra[2]], 2)
    R, c, ok = kabsch(Y, Xs, ws)
    # X ~ R (v - J0) + J0 + transl  =>  transl = c + R J0 - J0
    transl = c + (R @ J0[0][:, None])[..., 0] - J0[0]
    for p in range(P):
        good = np.flatnonzero(ok[p])
        if len(good) == 0:
            # no frame with a triangulated torso: upright, facing -Y, at the body centre
            from mamma_kit.body.lbs import UPRIGHT_ORIENT
            from mamma_kit.core.camera import rodrigues

            R[p] = rodrigues(UPRIGHT_ORIENT)
            good_c = np.flatnonzero(centre_ok[p])
            for t in range(T):
                src = good_c[np.argmin(np.abs(good_c - t))] if len(good_c) else t
                transl[p, t] = centres[p, src] - (R[p, t] @ (v0.mean(0) - J0[0])) - J0[0]
            continue
        for t in np.flatnonzero(~ok[p]):
            src = good[np.argmin(np.abs(good - t))]
            R[p, t] = R[p, src]
            cen = centres[p, t] if centre_ok[p, t] else centres[p, src]
            transl[p, t] = cen - (R[p, t] @ (v0.mean(0) - J0[0])) - J0[0]
    return R, transl, ok


# ---- hands from their own landmarks --------------------------------------------------------
HAND_WRISTS = (sk.JOINT_NAMES.index("left_wrist"), sk.JOINT_NAMES.index("right_wrist"))
MIN_PALM_LANDMARKS = 6  # triangulated palm landmarks a frame needs for a hand orientation (kabsch's own minimum)


def palm_landmarks(skin_weights: np.ndarray, wrist: int) -> np.ndarray:
    """Landmarks that move (mostly) rigidly with a hand: those whose dominant skinning
    joint is the wrist. skin_weights (L, 55) -> landmark indices (n,)."""
    return np.flatnonzero(np.asarray(skin_weights).argmax(1) == wrist)


def hand_orientations(rest_v: np.ndarray, rest_J: np.ndarray, X: np.ndarray, info: np.ndarray, palm: np.ndarray,
                      wrist: int) -> tuple[np.ndarray, np.ndarray]:
    """World rotation of a hand per person and frame from its triangulated palm landmarks.

    rest_v (P, L, 3) rest-pose landmarks and rest_J (P, 55, 3) joints at each person's shape;
    X (P, T, L, 3) triangulated landmarks with information weights info (P, T, L); palm (n,)
    the hand's palm landmarks. The palm in the rest pose, about its wrist, is fitted rigidly
    (weighted Kabsch) to its triangulated points: that gives the hand's world rotation G_wrist
    (the rest pose has every joint frame aligned with the world) whatever the arm is doing,
    so a hand that began palm-backwards need not find its way out of that minimum.
    Returns R (P, T, 3, 3) and ok (P, T) (at least MIN_PALM_LANDMARKS triangulated)."""
    Y = rest_v[:, None, palm] - rest_J[:, None, wrist:wrist + 1]  # (P, 1, n, 3)
    w = info[:, :, palm]
    R, _, ok = kabsch(np.broadcast_to(Y, X[:, :, palm].shape), X[:, :, palm], w)
    ok = ok & ((w > 0).sum(-1) >= MIN_PALM_LANDMARKS)
    return R, ok
