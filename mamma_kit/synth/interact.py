"""Making procedural motions physical: feet on the floor, hands that really touch.

``fit_floor_and_contacts`` adjusts a MotionClip in place:
1. interaction contacts: inverse kinematics on the arms (collar, shoulder, elbow, wrist)
   of all frames at once (torch, L-BFGS), pulling each palm centre to its target — the
   partner's palm (hand in hand) or a point 1.2 cm off the partner's chest/back surface —
   with a prior towards the procedural pose and temporal smoothness;
2. floor: per frame, the body is lifted so its lowest foot (or lowest vertex, for floor
   poses) touches z = 0, plus any jump height.
"""

from __future__ import annotations

import numpy as np
import torch

ARM_JOINTS = {"left": (13, 16, 18, 20), "right": (14, 17, 19, 21)}  # collar, shoulder, elbow, wrist
PALM_OFFSET = 0.012  # m: palm-centre distance to a touched surface (about half a hand's thickness)


def _palm_vertices(body, side: str) -> np.ndarray:
    """Vertices of the palm: hand vertices driven by the wrist, on the palm side (-Y at rest)."""
    from mamma_kit.body.skeleton import PART_NAMES

    v = body.np.v_template
    w = body.np.weights_dense
    wrist = 20 if side == "left" else 21
    hand_part = PART_NAMES.index(f"{side}_hand")
    cand = np.flatnonzero((body.vertex_part == hand_part) & (w[:, wrist] > 0.5))
    if len(cand) < 5:
        cand = np.flatnonzero(body.vertex_part == hand_part)
    y = v[cand, 1]
    return cand[y <= np.percentile(y, 35)]


def _anchor_vertices(body, part: str) -> np.ndarray:
    """Two surface vertices (left, right) on the upper chest or upper back."""
    from mamma_kit.body.skeleton import PART_NAMES

    v = body.np.v_template
    torso = np.flatnonzero(np.isin(body.vertex_part, [i for i, n in enumerate(PART_NAMES) if "torso" in n or "spine" in n or n == "chest"]))
    if not len(torso):
        torso = np.arange(len(v))
    j = body.np.J_template
    y_target = 0.5 * (j[9, 1] + j[12, 1])  # between spine3 and neck
    out = []
    for sx in (1, -1):
        x_target = sx * 0.09
        cand = torso[np.abs(v[torso, 1] - y_target) < 0.06]
        cand = cand[np.sign(v[cand, 0]) == sx] if len(cand) else torso
        z = v[cand, 2]
        sel = cand[z >= np.percentile(z, 90)] if part == "chest" else cand[z <= np.percentile(z, 10)]
        out.append(sel[np.argmin(np.abs(v[sel, 0] - x_target))])
    return np.array(out)


def fit_floor_and_contacts(body, clip, grounds: list[str], iters: int = 60) -> dict:
    """Adjust ``clip.params`` in place; returns diagnostics (final palm distance errors).
    Lying/sitting people ("lowest" ground) are placed before IK as well; arm IK could in
    principle lower a hand below their lowest point, which floor poses do not combine with."""
    diag = {}
    # feet first: arm IK leaves the feet where they are, so contacts made at the final
    # heights stay made (people of different heights are lifted by different amounts)
    _place_on_floor(body, clip, grounds)
    if clip.contacts:
        diag["contact_error_m"] = solve_contacts(body, clip, iters)
    return diag


def _place_on_floor(body, clip, grounds: list[str]) -> None:
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.body.skeleton import PART_NAMES

    feet = np.isin(body.vertex_part, [PART_NAMES.index("left_foot"), PART_NAMES.index("right_foot")])
    P, N = clip.params["transl"].shape[:2]
    for p in range(P):
        lift = clip.params["transl"][p, :, 2].copy()
        prm = {k: v[p] for k, v in clip.params.items() if k != "transl"}
        prm["betas"] = np.repeat(clip.betas[p][None], N, 0)
        verts, _ = pose_mesh_np(body, prm)  # without transl
        z = verts[..., 2]
        low = z[:, feet].min(1) if grounds[p] == "feet" else z.min(1)
        clip.params["transl"][p, :, 2] = -low + lift


IK_RATE = 15.0  # Hz: arm corrections are solved at this rate and interpolated in between


def solve_contacts(body, clip, iters: int) -> float:
    """Arm IK on a subsampled clip (IK_RATE), corrections interpolated to every sample."""
    times_all = clip.times
    dt = float(np.median(np.diff(times_all))) if len(times_all) > 1 else 1.0
    step = max(1, int(round(1.0 / (IK_RATE * dt))))
    keep = np.unique(np.r_[np.arange(0, len(times_all), step), len(times_all) - 1])
    if len(keep) == len(times_all):
        return _solve_contacts_dense(body, clip, iters)
    sub = type(clip)(times_all[keep], clip.betas, {k: v[:, keep].copy() for k, v in clip.params.items()},
                     clip.kind, [c | {"weight": np.asarray(c["weight"])[keep]} for c in clip.contacts])
    before = sub.params["body_pose"].copy()
    err = _solve_contacts_dense(body, sub, iters)
    delta = sub.params["body_pose"] - before  # (P, K, 63)
    for p in range(delta.shape[0]):
        for d in range(63):
            if np.any(delta[p, :, d]):
                clip.params["body_pose"][p, :, d] += np.interp(times_all, times_all[keep], delta[p, :, d])
    return err


def _solve_contacts_dense(body, clip, iters: int) -> float:
    from mamma_kit.body.lbs import pose_restricted

    P, N = clip.params["transl"].shape[:2]
    palms = {s: _palm_vertices(body, s) for s in ("left", "right")}
    anchors = {part: _anchor_vertices(body, part) for part in ("chest", "back")}
    all_ids = np.unique(np.concatenate([palms["left"], palms["right"], anchors["chest"], anchors["back"]]))
    pos_of = {int(v): i for i, v in enumerate(all_ids)}
    col = lambda arr: torch.tensor([pos_of[int(v)] for v in arr])  # noqa: E731

    dt = torch.float32
    base = {k: torch.tensor(v, dtype=dt) for k, v in clip.params.items()}
    betas = torch.tensor(clip.betas, dtype=dt)[:, None].expand(P, N, 16)
    # which arms move: every hand named in a contact
    moving = sorted({(c["a"][0], c["a"][1].split("_")[0]) for c in clip.contacts if "hand" in c["a"][1]} |
                    {(c["b"][0], c["b"][1].split("_")[0]) for c in clip.contacts if "hand" in c["b"][1]})
    joints = torch.zeros(P, 55, dtype=torch.bool)
    for p, side in moving:
        joints[p, list(ARM_JOINTS[side])] = True
    delta = torch.zeros(P, N, 21, 3, dtype=dt, requires_grad=True)  # body joints 1..21
    mask = joints[:, 1:22, None].to(dt)[:, None]  # (P, 1, 21, 1)

    def posed():
        prm = dict(base)
        prm["body_pose"] = base["body_pose"] + (delta * mask).reshape(P, N, 63)
        prm["betas"] = betas
        v, _ = pose_restricted(body, prm, all_ids)
        return v  # (P, N, len(all_ids), 3)

    def normals_out(v, part_ids, person):
        # outward direction at an anchor: away from the partner's pelvis axis, horizontal
        pelvis = base["transl"][person, :, :2]
        d = v[..., :2] - pelvis[:, None]
        d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        return torch.cat([d, torch.zeros_like(d[..., :1])], -1)

    weights = [torch.tensor(np.asarray(c["weight"], float), dtype=dt) for c in clip.contacts]

    def energy():
        v = posed()
        e = 0.0
        for c, w in zip(clip.contacts, weights):
            (pa, part_a), (pb, part_b) = c["a"], c["b"]
            if "hand" not in part_a:
                continue
            side_a = part_a.split("_")[0]
            palm_a = v[pa][:, col(palms[side_a])].mean(1)  # (N, 3)
            if "hand" in part_b:
                palm_b = v[pb][:, col(palms[part_b.split("_")[0]])].mean(1)
                gap = (palm_a - palm_b).norm(dim=-1)
                e = e + (w * (gap - 2 * PALM_OFFSET) ** 2).sum()
            else:
                k = 0 if side_a == "left" else 1
                # left hand to the partner's side that faces it: mirror for partners facing each other
                anchor_ids = col(anchors[part_b])
                target_v = v[pb][:, anchor_ids]  # (N, 2, 3)
                nrm = normals_out(target_v, None, pb)
                tgt = target_v + PALM_OFFSET * nrm
                dist = (palm_a[:, None] - tgt).norm(dim=-1).min(1).values
                e = e + (w * dist ** 2).sum()
        prior = (delta * mask).pow(2).sum() * 2e-3
        smooth = (delta[:, 1:] - delta[:, :-1]).pow(2).sum() * 2.0 if N > 1 else 0.0
        return e + prior + smooth

    opt = torch.optim.LBFGS([delta], lr=0.8, max_iter=iters, history_size=10, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = energy()
        loss.backward()
        return loss

    opt.step(closure)
    with torch.no_grad():
        clip.params["body_pose"] = (base["body_pose"] + (delta * mask).reshape(P, N, 63)).numpy().astype(np.float64)
        v = posed()
        errs = []
        for c, w in zip(clip.contacts, weights):
            (pa, part_a), (pb, part_b) = c["a"], c["b"]
            if "hand" in part_a and "hand" in part_b:
                ga = v[pa][:, col(palms[part_a.split("_")[0]])].mean(1)
                gb = v[pb][:, col(palms[part_b.split("_")[0]])].mean(1)
                on = w > 0.5
                if on.any():
                    errs.append(float(((ga - gb).norm(dim=-1) - 2 * PALM_OFFSET)[on].abs().max()))
    return max(errs) if errs else 0.0
