"""Linear blend skinning in torch, batched over any leading dims (e.g. people x frames).

A few pure tensor functions (shapes in the docstrings) and three entry points:

- ``pose_restricted(model, params, vertex_ids=None)``: only the selected vertices (default:
  the 512 landmarks) and the 55 joints, differentiable. The fit's inner loop.
- ``pose_mesh(model, params)``: every vertex (export, rendering, contact), differentiable.
- ``pose_mesh_np(model, params)``: numpy in, float32 numpy out, no grad, chunked over
  frames; for renderers and synthesis.

Parameters follow SMPL-X (DESIGN.md): a dict with any of betas (..., 16), global_orient (..., 3),
body_pose (..., 63), left_hand_pose / right_hand_pose (..., 45), jaw_pose / leye_pose /
reye_pose (..., 3), expression (..., 10), transl (..., 3); axis-angle; missing keys are zero.
Leading dims broadcast like torch: per-person betas (P, 16) with per-frame poses (P, T, 63)
must be given as betas[:, None]. Shape blending runs on the betas' own leading dims, so
shapes shared over frames cost nothing per frame.

The result equals ``smplx.SMPLX(..., use_pca=False, flat_hand_mean=True)``: rest joints
J = J_regressor @ (v_template + shapedirs betas + exprdirs expression); pose correctives
from (R_j - I) of joints 1..54; every joint rotates about its rest position; a vertex is
sum_k w_k (R_k v + t_k) + transl. global_orient rotates about the rest pelvis joint (not
the origin) and transl is added last. No world rotation is baked in: the model's canonical
frame is Y up, facing +Z, so an upright person in mamma-kit's Z-up world needs a
global_orient whose rotation takes +Y to +Z (e.g. ``UPRIGHT_ORIENT``, facing -Y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np
import torch

from mamma_kit.body import skeleton as sk

#: global_orient (axis-angle, +90 deg about X) that turns the canonical Y-up body upright in
#: the Z-up world (+Y -> +Z, facing +Z -> facing -Y).
UPRIGHT_ORIENT = np.array([math.pi / 2, 0.0, 0.0])

_POSE_ORDER = ["global_orient", "body_pose", "jaw_pose", "leye_pose", "reye_pose",
               "left_hand_pose", "right_hand_pose"]  # SMPL-X full-pose order (55 joints)


def axis_angle_to_matrix(aa: torch.Tensor) -> torch.Tensor:
    """Rodrigues: (..., 3) axis-angle -> (..., 3, 3) rotation, smooth (finite gradients) at 0."""
    x, y, z = aa.unbind(-1)
    th2 = x * x + y * y + z * z
    small = th2 < 1e-8
    th2s = torch.where(small, torch.ones_like(th2), th2)
    th = torch.sqrt(th2s)
    a = torch.where(small, 1.0 - th2 / 6.0, torch.sin(th) / th)             # sin(t)/t
    b = torch.where(small, 0.5 - th2 / 24.0, (1.0 - torch.cos(th)) / th2s)  # (1-cos t)/t^2
    # R = I + a [v]x + b (v v^T - t^2 I)
    c = 1.0 - b * th2
    R = torch.stack([
        c + b * x * x, b * x * y - a * z, b * x * z + a * y,
        b * x * y + a * z, c + b * y * y, b * y * z - a * x,
        b * x * z - a * y, b * y * z + a * x, c + b * z * z,
    ], dim=-1)
    return R.reshape(*aa.shape[:-1], 3, 3)


def prepare_params(params: Mapping[str, object], dtype=torch.float32,
                   device: torch.device | str = "cpu") -> tuple[dict[str, torch.Tensor], torch.Size]:
    """Tensors for every parameter (missing ones are zero) and the broadcast leading shape.

    Accepts numpy arrays or tensors (tensors keep their autograd graph). Raises ValueError
    on a wrong last dimension or an unknown key.
    """
    out: dict[str, torch.Tensor] = {}
    leads = []
    for k, v in params.items():
        if k not in sk.PARAM_SIZES:
            if k in ("joints", "frame_times", "fps", "body_model", "gender", "producer"):
                continue  # result-file keys that are not parameters
            raise ValueError(f"unknown SMPL-X parameter {k!r}")
        if v is None:
            continue
        t = v if isinstance(v, torch.Tensor) else torch.as_tensor(np.asarray(v))
        t = t.to(dtype=dtype, device=device)
        if t.ndim == 0 or t.shape[-1] != sk.PARAM_SIZES[k]:
            raise ValueError(f"{k} must end in {sk.PARAM_SIZES[k]}, got shape {tuple(t.shape)}")
        out[k] = t
        leads.append(t.shape[:-1])
    lead = torch.broadcast_shapes(*leads) if leads else torch.Size([])
    return out, lead


def full_pose(p: Mapping[str, torch.Tensor], lead: torch.Size, dtype=torch.float32,
              device: torch.device | str = "cpu") -> torch.Tensor:
    """(*lead, 55, 3) axis-angle of all joints in SMPL-X order from prepared parameters."""
    parts = []
    for k in _POSE_ORDER:
        n = sk.POSE_PARAMS[k]
        if k in p:
            parts.append(p[k].expand(*lead, n))
        else:
            parts.append(torch.zeros(*lead, n, dtype=dtype, device=device))
    return torch.cat(parts, -1).reshape(*lead, sk.NUM_JOINTS, 3)


def shape_blend(template_n3: torch.Tensor, dirs_n3b: torch.Tensor, coeffs: torch.Tensor) -> torch.Tensor:
    """template (N, 3) + dirs (N, 3, B) . coeffs (..., B) -> (..., N, 3)."""
    N = template_n3.shape[0]
    flat = coeffs @ dirs_n3b.reshape(N * 3, -1).T  # (..., N*3)
    return template_n3 + flat.reshape(*coeffs.shape[:-1], N, 3)


def _level_plan(parents: np.ndarray):
    """Joints sorted by tree level: the permutation into level order, the slice of each
    level in it, each level's parents as positions within the previous level (parents of a
    level all sit in the level before it), and the inverse permutation."""
    levels = sk.tree_levels(parents)
    order = np.concatenate(levels)
    pos = np.zeros(len(parents), dtype=np.int64)
    slices, start = [], 0
    for idx in levels:
        pos[idx] = np.arange(len(idx))
        slices.append(slice(start, start + len(idx)))
        start += len(idx)
    par_pos = [torch.as_tensor(pos[np.maximum(parents[idx], 0)]) for idx in levels]
    return torch.as_tensor(order), slices, par_pos, torch.as_tensor(np.argsort(order))


_PLANS: dict[bytes, tuple] = {}


def forward_kinematics(rot_j33: torch.Tensor, joints_j3: torch.Tensor,
                       parents: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """World rotation and position of every joint.

    rot_j33: (..., J, 3, 3) local rotations; joints_j3: (..., J, 3) rest joint positions
    (broadcastable to rot's leading dims). Returns R (..., J, 3, 3) and p (..., J, 3), the
    posed joint positions (no translation).

    Local transforms [R | offset to the parent] are put in tree-level order once; then one
    batched product per level (11 for SMPL-X) on contiguous slices, no loop over joints.
    (Pointer jumping, 4 steps over all joints, did 4x the arithmetic and measured slower.)
    """
    parents = np.asarray(parents)
    key = parents.tobytes()
    if key not in _PLANS:
        _PLANS[key] = _level_plan(parents)
    order, slices, par_pos, inverse = _PLANS[key]
    lead = torch.broadcast_shapes(rot_j33.shape[:-3], joints_j3.shape[:-2])
    par = torch.as_tensor(np.where(parents < 0, len(parents), parents))
    j_par = torch.cat([joints_j3, torch.zeros_like(joints_j3[..., :1, :])], -2).index_select(-2, par)
    offset = joints_j3 - j_par  # a root's offset is its own position
    local = torch.cat([rot_j33.expand(*lead, *rot_j33.shape[-3:]),
                       offset.expand(*lead, *offset.shape[-2:]).unsqueeze(-1)], -1).index_select(-3, order)
    # torch.split, not slicing: a slice's backward fills a full-size zero tensor per level
    locs = torch.split(local, [sl.stop - sl.start for sl in slices], dim=-3)
    Ts = [locs[0]]  # per level (..., n, 3, 4) world [R | p]
    for loc, pp in zip(locs[1:], par_pos[1:]):
        R_par, p_par = Ts[-1].index_select(-3, pp).split([3, 1], -1)
        RT, Rt = (R_par @ loc).split([3, 1], -1)  # [R_par R | R_par offset]
        Ts.append(torch.cat([RT, Rt + p_par], -1))
    R, p = torch.cat(Ts, -3).index_select(-3, inverse).split([3, 1], -1)
    return R, p.squeeze(-1)


def skinning_transforms(R_j33: torch.Tensor, p_j3: torch.Tensor, joints_j3: torch.Tensor) -> torch.Tensor:
    """(..., J, 12): per-joint [R | p - R j_rest] rows flattened (3 x 4), maps rest to posed."""
    t = p_j3 - (R_j33 @ joints_j3.unsqueeze(-1)).squeeze(-1)
    return torch.cat([R_j33, t.unsqueeze(-1)], -1).flatten(-2)


def skin_sparse(points_n3: torch.Tensor, A_j12: torch.Tensor, idx_nk: torch.Tensor, w_nk: torch.Tensor) -> torch.Tensor:
    """Blend the K non-zero joint transforms of each point and apply them.

    points (..., N, 3); A (..., J, 12); idx, w (N, K). Returns (..., N, 3).
    """
    N, K = idx_nk.shape
    A_nk = A_j12[..., idx_nk.reshape(-1), :].reshape(*A_j12.shape[:-2], N, K, 12)
    T = (A_nk * w_nk.unsqueeze(-1)).sum(-2).reshape(*A_nk.shape[:-3], N, 3, 4)
    return (T[..., :3] * points_n3.unsqueeze(-2)).sum(-1) + T[..., 3]


def skin_dense(points_n3: torch.Tensor, A_j12: torch.Tensor, W_nj: torch.Tensor) -> torch.Tensor:
    """Same as skin_sparse with dense weights W (N, J): one matrix product blends the transforms."""
    T = (W_nj @ A_j12).reshape(*A_j12.shape[:-2], W_nj.shape[0], 3, 4)
    return (T[..., :3] * points_n3.unsqueeze(-2)).sum(-1) + T[..., 3]


def skin_shared_points(points_gn3: torch.Tensor, A_grj12: torch.Tensor, W_nj: torch.Tensor) -> torch.Tensor:
    """Skinning when R poses share each rest point set (one shape, many frames).

    points (G, N, 3) rest points per group; A (G, R, J, 12) transforms of the R poses of each
    group; W (N, J). Returns (G, R, N, 3). Folding the points into the weights, M[n, (j, d)]
    = W[n, j] [p_n; 1]_d, makes the whole blend-and-apply one GEMM per group,
    (N, 4J) @ (4J, 3R), with no (R, N, 12) intermediate: the fastest form measured here
    (benchmarks/body_lbs.py), faster than gathering the K non-zero weights.
    """
    G, N, _ = points_gn3.shape
    R, J = A_grj12.shape[1], A_grj12.shape[2]
    ph = torch.cat([points_gn3, torch.ones_like(points_gn3[..., :1])], -1)  # (G, N, 4)
    M = (W_nj.unsqueeze(-1) * ph.unsqueeze(-2)).reshape(G, N, J * 4)
    Am = A_grj12.reshape(G, R, J, 3, 4).permute(0, 2, 4, 1, 3).reshape(G, J * 4, R * 3)
    return (M @ Am).reshape(G, N, R, 3).permute(0, 2, 1, 3)


#: vertices skinned together: each group's vertices depend on few joints (a limb and its
#: neighbours), so per group the blend is a small dense GEMM over just those joints
PART_GROUPS = (("head", "neck"), ("torso", "pelvis"), ("left_upper_arm", "left_lower_arm", "left_hand"),
               ("right_upper_arm", "right_lower_arm", "right_hand"),
               ("left_upper_leg", "left_lower_leg", "left_foot"), ("right_upper_leg", "right_lower_leg", "right_foot"))


@dataclass
class SkinBlocks:
    """Vertices grouped with the joints they depend on. order (N,): vertices by group;
    inverse (N,); per group b: verts[b] (n_b,) and joints[b] (j_b,) indices and W[b] (n_b, j_b)."""

    order: torch.Tensor
    inverse: torch.Tensor
    verts: list[torch.Tensor]
    joints: list[torch.Tensor]
    W: list[torch.Tensor]

    @classmethod
    def build(cls, W_nj: torch.Tensor, part_n: np.ndarray) -> "SkinBlocks":
        names = list(sk.PART_NAMES)
        group_of = np.zeros(len(names), np.int64) + len(PART_GROUPS)
        for g, members in enumerate(PART_GROUPS):
            for m in members:
                if m in names:
                    group_of[names.index(m)] = g
        grp = group_of[np.asarray(part_n)]
        Wn = W_nj.numpy()
        verts, joints, Ws = [], [], []
        for g in np.unique(grp):
            v = np.flatnonzero(grp == g)
            j = np.flatnonzero((Wn[v] > 0).any(0))
            verts.append(torch.as_tensor(v))
            joints.append(torch.as_tensor(j))
            Ws.append(W_nj[v][:, j].contiguous())
        order = torch.cat(verts)
        return cls(order, torch.argsort(order), verts, joints, Ws)


def skin_shared_blocks(points_gn3: torch.Tensor, A_grj12: torch.Tensor, blocks: SkinBlocks) -> torch.Tensor:
    """skin_shared_points, one small GEMM per vertex group over only the joints it uses
    (about a fifth of the dense product's work for SMPL-X-like weights). Returns (G, R, N, 3)."""
    outs = [skin_shared_points(points_gn3.index_select(1, v), A_grj12.index_select(2, j), W)
            for v, j, W in zip(blocks.verts, blocks.joints, blocks.W)]
    return torch.cat(outs, 2).index_select(2, blocks.inverse)


def skin(points: torch.Tensor, A_j12: torch.Tensor, W_nj: torch.Tensor, idx_nk: torch.Tensor | None = None,
         w_nk: torch.Tensor | None = None, blocks: SkinBlocks | None = None) -> torch.Tensor:
    """Posed points (*lead, N, 3) from rest points (*vlead, N, 3) and transforms (*lead, J, 12).

    When the rest points are shared by trailing leading dims (betas (P, 1, 16) with poses
    (P, T, ...)), uses skin_shared_points; otherwise blends per point (dense GEMM, or the
    sparse K-weight gather when idx/w are given).
    """
    lead = A_j12.shape[:-2]
    N = points.shape[-2]
    vlead = (1,) * (len(lead) - (points.ndim - 2)) + tuple(points.shape[:-2])
    k = 0
    while k < len(lead) and vlead[k] == lead[k]:
        k += 1
    shared = all(d == 1 for d in vlead[k:]) and math.prod(vlead) < math.prod(lead)
    if shared and idx_nk is None:
        G, R = math.prod(lead[:k]), math.prod(lead[k:])
        pts = points.reshape(G, N, 3)
        A = A_j12.reshape(G, R, *A_j12.shape[-2:])
        out = skin_shared_blocks(pts, A, blocks) if blocks is not None else skin_shared_points(pts, A, W_nj)
        return out.reshape(*lead, N, 3)
    if idx_nk is not None:
        return skin_sparse(points, A_j12, idx_nk, w_nk)
    return skin_dense(points, A_j12, W_nj)


@dataclass
class RestrictedBody:
    """The model's data gathered at N selected vertices (built once, see BodyModel.restricted).

    ids (N,); v_template (N, 3); shapedirs (N, 3, B); exprdirs (N, 3, E) or None;
    posedirs (486, N*3) or None; skin_idx, skin_w (N, K); W (N, J) dense weights.
    """

    ids: np.ndarray
    v_template: torch.Tensor
    shapedirs: torch.Tensor
    exprdirs: torch.Tensor | None
    posedirs: torch.Tensor | None
    skin_idx: torch.Tensor
    skin_w: torch.Tensor
    W: torch.Tensor
    blocks: SkinBlocks | None = None

    @classmethod
    def build(cls, model, ids: np.ndarray) -> "RestrictedBody":
        it = torch.as_tensor(np.asarray(ids, dtype=np.int64))
        pd = None
        if model.posedirs is not None:
            pd = model.posedirs[it].reshape(len(it) * 3, -1).T.contiguous()
        # keep only as many weight slots as these vertices need
        w = model.skin_w[it]
        k = max(1, int((w > 0).sum(1).max()))
        return cls(ids=np.asarray(ids, dtype=np.int64), v_template=model.v_template[it].contiguous(),
                   shapedirs=model.shapedirs[it].contiguous(),
                   exprdirs=None if model.exprdirs is None else model.exprdirs[it].contiguous(),
                   posedirs=pd, skin_idx=model.skin_idx[it, :k].contiguous(), skin_w=w[:, :k].contiguous(),
                   W=model.weights_dense[it].contiguous(),
                   blocks=SkinBlocks.build(model.weights_dense[it], np.asarray(model.vertex_part)[np.asarray(ids)]))


def _pose(model, rb: RestrictedBody | None, params: Mapping[str, object], sparse: bool):
    dtype, device = model.v_template.dtype, model.v_template.device
    p, lead = prepare_params(params, dtype, device)
    betas = p.get("betas", torch.zeros(sk.NUM_BETAS, dtype=dtype, device=device))
    expr = p.get("expression") if model.exprdirs is not None else None

    # rest joints (never touching V): J = J_template + J_shapedirs . betas (+ expression)
    J_rest = shape_blend(model.J_template, model.J_shapedirs, betas)
    if expr is not None:
        J_rest = J_rest + (expr @ model.J_exprdirs.reshape(-1, expr.shape[-1]).T).reshape(*expr.shape[:-1], -1, 3)

    aa = full_pose(p, lead, dtype, device)
    rot = axis_angle_to_matrix(aa)  # (*lead, 55, 3, 3)
    R, pj = forward_kinematics(rot, J_rest, model.parents.numpy())
    A = skinning_transforms(R, pj, J_rest)

    data = rb if rb is not None else model
    v = shape_blend(data.v_template, data.shapedirs, betas)
    if expr is not None:
        v = v + shape_blend(torch.zeros_like(data.v_template), data.exprdirs, expr)
    if data.posedirs is not None:
        eye = torch.eye(3, dtype=dtype, device=device)
        feat = (rot[..., 1:, :, :] - eye).flatten(-3)  # (*lead, 486)
        pd = data.posedirs if rb is not None else model.posedirs.reshape(-1, feat.shape[-1]).T
        v = v + (feat @ pd).reshape(*lead, -1, 3)
    W = data.W if rb is not None else model.weights_dense
    blocks = rb.blocks if rb is not None else model.skin_blocks()
    verts = skin(v, A, W, data.skin_idx, data.skin_w) if sparse else skin(v, A, W, blocks=blocks)
    if "transl" in p:
        t = p["transl"].unsqueeze(-2)
        verts = verts + t
        pj = pj + t
    return verts, pj.expand(*lead, sk.NUM_JOINTS, 3)


def pose_restricted(model, params: Mapping[str, object], vertex_ids: np.ndarray | None = None,
                    sparse: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Posed vertices at ``vertex_ids`` (default: model.landmark_ids) and the 55 joints.

    Returns verts (*lead, N, 3) and joints (*lead, 55, 3), differentiable w.r.t. every
    parameter tensor. ``sparse=True`` forces the K-weight gather blend (slower here; kept
    for comparison in benchmarks/body_lbs.py).
    """
    return _pose(model, model.restricted(vertex_ids), params, sparse)


def pose_mesh(model, params: Mapping[str, object]) -> tuple[torch.Tensor, torch.Tensor]:
    """All posed vertices (*lead, V, 3) and joints (*lead, 55, 3), differentiable."""
    return _pose(model, None, params, sparse=False)


def pose_mesh_np(model, params: Mapping[str, object], chunk: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """No-grad full mesh for many frames: params as numpy (or tensors) with any leading dims;
    returns float32 verts (*lead, V, 3) and joints (*lead, 55, 3).

    Frames are grouped by their shape (betas, expression) rows, so per-frame copies of a few
    people's betas still take the fast shared-rest-mesh path, and processed ``chunk`` frames
    at a time to bound memory.
    """
    with torch.no_grad():
        p, lead = prepare_params(params)
        if len(lead) == 0:
            v, j = _pose(model, None, p, sparse=False)
            return v.numpy(), j.numpy()
        n = math.prod(lead)
        flat = {k: t.expand(*lead, t.shape[-1]).reshape(n, t.shape[-1]) for k, t in p.items()}
        shape_keys = [k for k in ("betas", "expression") if k in flat]
        if shape_keys:
            rows = torch.cat([flat[k] for k in shape_keys], -1).numpy()
            uniq, group = np.unique(rows, axis=0, return_inverse=True)
        else:
            uniq, group = np.zeros((1, 0)), np.zeros(n, dtype=np.int64)
        V = model.num_vertices
        verts = np.empty((n, V, 3), np.float32)
        joints = np.empty((n, sk.NUM_JOINTS, 3), np.float32)
        for g in range(len(uniq)):  # one group per distinct body shape (a few people)
            ids = np.flatnonzero(group.reshape(-1) == g)
            for s in range(0, len(ids), chunk):
                sel = torch.as_tensor(ids[s:s + chunk])
                sub = {k: (t[sel[:1]][0] if k in shape_keys else t[sel]) for k, t in flat.items()}
                v, j = _pose(model, None, sub, sparse=False)
                verts[ids[s:s + chunk]] = v.numpy()
                joints[ids[s:s + chunk]] = j.numpy()
        return verts.reshape(*lead, V, 3), joints.reshape(*lead, sk.NUM_JOINTS, 3)
