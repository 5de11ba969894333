"""A regressor from the body's vertices to BlazePose's 33 points (the fit's keypoint energy).

BlazePose's points are not the skeleton's joints: its hips sit outside the hip joints, its
heels and toes on the skin, its shoulders above the shoulder joints. The fit compares the
detector's points with points of the body, so each of the 33 points is a convex
combination of nearby vertices, X_k = sum_v W_kv V_v (W >= 0, rows sum to 1, a few dozen
vertices each), learned where the true bodies are known and BlazePose ran on the renders.

Learning (``learn_regressor``): per point, the support is the vertices near its anchor on
the skeleton (ANCHORS: a joint, a named surface vertex, or an offset from one) in the rest
pose; the initial guess W0 is the non-negative combination of them nearest the anchor.
Each detection (camera c known, true posed vertices V) gives two equations linear in the
weights: with the detection's normalised (undistorted) coordinates (x, y) and the camera's
rows R_i, t_i,  sum_v w_v [x (R_3 V_v + t_3) - (R_1 V_v + t_1)] = 0  (and the same with y,
R_2), scaled by f / (depth * box height) so a residual is a fraction of the person's box
height. Rows are weighted by BlazePose's visibility, a small ridge pulls toward W0 and one
heavy row toward sum w = 1; scipy's lsq_linear keeps w >= 0. Robust rounds reweight rows by
Geman-McClure on the residuals (scale from their median), so the detector's gross errors
(a swapped left/right, a limb on the wrong person) lose their say. ``sigma_frac`` (33,) is
the robust residual scale of each point after learning (fraction of the box height): the
fit's sigma for that point.

The shipped file (data/open_body_blazepose33.npz, see data/NOTICE) was made by
``benchmarks/kp_regressor.py --write`` (which calls ``learn_regressor``); it holds ids
(33, S) vertex ids, weights (33, S), sigma_frac (33,), the body model's sha256 and a
provenance JSON. ``keypoint_regressor(model)`` loads it for the open body; for another
body model (e.g. SMPL-X) it returns the initial guess built on that model, marked unlearned.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mamma_kit.body import skeleton as sk

DATA_FILE = Path(__file__).resolve().parent / "data" / "open_body_blazepose33.npz"

#: BlazePose GHUM's 33 points (MediaPipe pose landmark order).
POINT_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index")
N_POINTS = len(POINT_NAMES)

# anchor of each point on the body, in the rest pose (SMPL-X frame: Y up, +Z forward, the
# person's left at +X): (kind, name, offset m). "joint": a skeleton joint; "vertex": a named
# extra vertex (skeleton.EXTRA_JOINT_NAMES); the offset moves the anchor (eye corners, mouth).
ANCHORS = (
    ("vertex", "nose", (0, 0, 0)),
    ("vertex", "left_eye", (-0.012, 0, 0)), ("vertex", "left_eye", (0, 0, 0)), ("vertex", "left_eye", (0.014, 0, 0)),
    ("vertex", "right_eye", (0.012, 0, 0)), ("vertex", "right_eye", (0, 0, 0)),
    ("vertex", "right_eye", (-0.014, 0, 0)),
    ("vertex", "left_ear", (0, 0, 0)), ("vertex", "right_ear", (0, 0, 0)),
    ("vertex", "nose", (0.024, -0.045, -0.01)), ("vertex", "nose", (-0.024, -0.045, -0.01)),
    ("joint", "left_shoulder", (0, 0, 0)), ("joint", "right_shoulder", (0, 0, 0)),
    ("joint", "left_elbow", (0, 0, 0)), ("joint", "right_elbow", (0, 0, 0)),
    ("joint", "left_wrist", (0, 0, 0)), ("joint", "right_wrist", (0, 0, 0)),
    ("joint", "left_pinky1", (0, 0, 0)), ("joint", "right_pinky1", (0, 0, 0)),
    ("joint", "left_index2", (0, 0, 0)), ("joint", "right_index2", (0, 0, 0)),
    ("joint", "left_thumb2", (0, 0, 0)), ("joint", "right_thumb2", (0, 0, 0)),
    ("joint", "left_hip", (0, 0, 0)), ("joint", "right_hip", (0, 0, 0)),
    ("joint", "left_knee", (0, 0, 0)), ("joint", "right_knee", (0, 0, 0)),
    ("joint", "left_ankle", (0, 0, 0)), ("joint", "right_ankle", (0, 0, 0)),
    ("vertex", "left_heel", (0, 0, 0)), ("vertex", "right_heel", (0, 0, 0)),
    ("vertex", "left_big_toe", (0, 0, 0)), ("vertex", "right_big_toe", (0, 0, 0)),
)
# without named extra vertices (real SMPL-X files carry none): the nearest joint
FALLBACK_JOINT = {"nose": "head", "left_eye": "left_eye_smplhf", "right_eye": "right_eye_smplhf",
                  "left_ear": "head", "right_ear": "head", "left_heel": "left_ankle", "right_heel": "right_ankle",
                  "left_big_toe": "left_foot", "right_big_toe": "right_foot"}
#: points that move (nearly) rigidly with the head and trunk: stage 1 and the Procrustes start
RIGID_POINTS = tuple(range(0, 13)) + (23, 24)
SUPPORT = 64  # vertices per point
SIGMA_FRAC_DEFAULT = 0.03  # fraction of the box height when nothing was learned (BlazePose: a few %)


@dataclass
class KeypointRegressor:
    """ids (33, S) vertex ids, weights (33, S) >= 0 with rows summing to 1, sigma_frac (33,)."""

    ids: np.ndarray
    weights: np.ndarray
    sigma_frac: np.ndarray
    body_sha256: str = ""
    learned: bool = False
    provenance: dict = field(default_factory=dict)

    @property
    def n_points(self) -> int:
        return int(self.ids.shape[0])

    def dense(self, n_vertices: int) -> np.ndarray:
        """W_kv (33, V) dense weight matrix."""
        W = np.zeros((self.n_points, n_vertices))
        np.add.at(W, (np.repeat(np.arange(self.n_points), self.ids.shape[1]), self.ids.reshape(-1)),
                  self.weights.reshape(-1))
        return W

    def apply(self, verts_vn3: np.ndarray, vertex_ids: np.ndarray | None = None) -> np.ndarray:
        """Posed vertices (..., V, 3) -> the 33 points (..., 33, 3). With ``vertex_ids`` (U,)
        the vertices given are only those (..., U, 3), which must hold every support vertex."""
        ids = self.ids
        if vertex_ids is not None:
            pos = np.full(int(max(vertex_ids.max(), ids.max())) + 1, -1, np.int64)
            pos[vertex_ids] = np.arange(len(vertex_ids))
            ids = pos[ids]
            if (ids < 0).any():
                raise ValueError("vertex_ids miss some of the regressor's support vertices")
        return np.einsum("ks,...ksd->...kd", self.weights, verts_vn3[..., ids, :])

    def save(self, path: str | Path) -> Path:
        from mamma_kit.core.io import write_npz

        return write_npz(path, ids=self.ids.astype(np.int32), weights=self.weights.astype(np.float32),
                         sigma_frac=self.sigma_frac.astype(np.float32), point_names=np.array(POINT_NAMES),
                         body_sha256=np.array(self.body_sha256), provenance=np.array(json.dumps(self.provenance)))

    @classmethod
    def load(cls, path: str | Path) -> "KeypointRegressor":
        from mamma_kit.core.io import read_npz

        d = read_npz(path, "keypoint regressor")
        return cls(d["ids"].astype(np.int64), d["weights"].astype(np.float64), d["sigma_frac"].astype(np.float64),
                   str(d["body_sha256"]), True, json.loads(str(d["provenance"])))


def anchor_points(model) -> np.ndarray:
    """The 33 anchors (33, 3) on the rest body at zero shape (m)."""
    v = model.v_template.numpy().astype(np.float64)
    J = model.J_template.numpy().astype(np.float64)
    extra = None if model.extra_joint_ids is None else dict(zip(sk.EXTRA_JOINT_NAMES, model.extra_joint_ids))
    out = np.zeros((N_POINTS, 3))
    for k, (kind, name, off) in enumerate(ANCHORS):
        if kind == "vertex" and extra is not None:
            out[k] = v[extra[name]]
        else:
            out[k] = J[sk.JOINT_NAMES.index(FALLBACK_JOINT.get(name, name) if kind == "vertex" else name)]
        out[k] += np.asarray(off, float)
    return out


def naive_points(model, verts_vn3: np.ndarray, joints_j3: np.ndarray, vertex_ids: np.ndarray | None = None) -> np.ndarray:
    """The naive correspondence: each point taken as its anchor's joint or named vertex
    (offsets ignored; eye corners and mouth at the eye and nose). (..., 33, 3). With
    ``vertex_ids`` the vertices given are only those (as in KeypointRegressor.apply)."""
    extra = None if model.extra_joint_ids is None else dict(zip(sk.EXTRA_JOINT_NAMES, model.extra_joint_ids))
    if extra is not None and vertex_ids is not None:
        where = {int(v): i for i, v in enumerate(vertex_ids)}
        extra = {n: where[int(v)] for n, v in extra.items()}
    cols = []
    for kind, name, _ in ANCHORS:
        if kind == "vertex" and extra is not None:
            cols.append(verts_vn3[..., extra[name], :])
        else:
            cols.append(joints_j3[..., sk.JOINT_NAMES.index(FALLBACK_JOINT.get(name, name) if kind == "vertex"
                                                            else name), :])
    return np.stack(cols, -2)


def anchor_weights(V_s3: np.ndarray, anchor_3: np.ndarray, lam: float = 1e-3) -> np.ndarray:
    """(S,) the non-negative weights, summing to 1, of the support vertices V_s3 whose combination is
    nearest the anchor, mildly spread by a ridge toward equal weights (a point, not one vertex)."""
    from scipy.optimize import lsq_linear

    S = len(V_s3)
    A = np.vstack([V_s3.T, 10.0 * np.ones((1, S)), np.sqrt(lam) * np.eye(S)])
    b = np.r_[anchor_3, 10.0, np.full(S, np.sqrt(lam) / S)]
    w = lsq_linear(A, b, bounds=(0, np.inf)).x
    return w / w.sum()


def initial_regressor(model, support: int = SUPPORT) -> KeypointRegressor:
    """Support and initial weights on ``model`` (see module doc): per point the ``support``
    vertices nearest its anchor (for a joint inside the body, spread around it: the 6 x
    support nearest thinned by farthest-point sampling), weighted to reproduce the anchor."""
    v = model.v_template.numpy().astype(np.float64)
    anchors = anchor_points(model)
    ids = np.zeros((N_POINTS, support), np.int64)
    W = np.zeros((N_POINTS, support))
    for k, a in enumerate(anchors):
        d = np.linalg.norm(v - a, axis=1)
        if ANCHORS[k][0] == "joint":
            near = np.argsort(d)[:6 * support]
            pick = [int(near[0])]
            dm = np.linalg.norm(v[near] - v[near[0]], axis=1)
            while len(pick) < support:
                i = int(np.argmax(dm))
                pick.append(int(near[i]))
                dm = np.minimum(dm, np.linalg.norm(v[near] - v[near[i]], axis=1))
            ids[k] = np.sort(pick)
        else:
            ids[k] = np.sort(np.argsort(d)[:support])
        W[k] = anchor_weights(v[ids[k]], a)
    return KeypointRegressor(ids, W, np.full(N_POINTS, SIGMA_FRAC_DEFAULT), model.sha256, False,
                             {"made_by": "initial_regressor (anchors on the skeleton, not learned)"})


def keypoint_regressor(model) -> KeypointRegressor:
    """The learned regressor for the open body; for another body model the initial guess
    on that model (``learned`` False)."""
    if DATA_FILE.is_file():
        reg = KeypointRegressor.load(DATA_FILE)
        if reg.body_sha256 == model.sha256:
            return reg
    return initial_regressor(model)


# ---- learning -------------------------------------------------------------------------------

@dataclass
class Detections:
    """Pairs of (true body, camera, BlazePose detection) for every point, from synthetic
    workspaces: V (N, U, 3) true posed vertices at the support union ``union`` (U,);
    rows (N, 2, 4) the camera's equations [x R_3 - R_1, x t_3 - t_1] and the same for y, per
    detection, scaled to fractions of the box height at the anchor's depth; xy (N, 33, 2)
    detections px; vis (N, 33) visibility x presence; box_h (N,) true box height px;
    cam/ws (N,) indices; proj naive (N, 33, 2) px of the naive correspondence."""

    union: np.ndarray
    V: np.ndarray
    R: np.ndarray
    t: np.ndarray
    K: list
    cam_index: np.ndarray
    xn: np.ndarray
    scale: np.ndarray
    xy: np.ndarray
    vis: np.ndarray
    box_h: np.ndarray
    naive_px: np.ndarray
    cams: list
    source: np.ndarray


def collect_detections(workspaces: list, model, reg0: KeypointRegressor, min_area: int = 50) -> Detections:
    """Read every (camera, frame, person) with BlazePose points on a ground-truth-mask track
    (track id = person id) from synthetic workspaces; see Detections."""
    import torch

    from mamma_kit.body.lbs import pose_restricted
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.errors import UserError
    from mamma_kit.core.smplxfile import read_smplx_result
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import KeypointTracks, MaskTracks
    from mamma_kit.core.workspace import Workspace

    union = np.unique(np.r_[reg0.ids.reshape(-1), model.extra_joint_ids if model.extra_joint_ids is not None else []])
    out = {k: [] for k in ("V", "cam", "xn", "scale", "xy", "vis", "h", "naive", "src")}
    cams = []
    for wi, root in enumerate(workspaces):
        ws = Workspace(Path(root))
        if not (ws.gt_dir / "smplx").is_dir():
            raise UserError(f"{root} has no gt/smplx (not a synthetic workspace)", "pass workspaces made by `mamma-kit synth`")
        rig, _ = read_calibration(ws.gt_dir / "calibration.toml")
        clocks, _ = read_timing(ws.gt_dir / "timing.toml")
        people = {}
        for f in sorted((ws.gt_dir / "smplx").glob("person_*.npz")):
            r = read_smplx_result(f)
            with torch.no_grad():
                pr = {k: torch.as_tensor(np.asarray(v), dtype=torch.float32) for k, v in r.params().items()}
                vv, jj = pose_restricted(model, pr, union)
            people[int(f.stem.split("_")[1])] = (r.frame_times, vv.numpy().astype(np.float64),
                                                 jj.numpy().astype(np.float64))
        for cam in rig.names:
            if not ws.keypoints_file(cam).is_file():
                continue
            kt = KeypointTracks.load(ws.keypoints_file(cam))
            gt = MaskTracks.load(ws.gt_dir / "masks" / f"{cam}.npz")
            if len(kt.frame_times) != len(gt.frame_times) or not np.allclose(kt.frame_times, gt.frame_times):
                raise UserError(f"{root}: keypoints/{cam}.npz is not on the ground-truth masks' frames",
                                "run `mamma-kit track --backend gt` then `mamma-kit keypoints` on the workspace")
            c = rig[cam]
            ci = len(cams)
            cams.append(c)
            t_ref = clocks[cam].to_ref(kt.frame_times)
            gcol = {int(p): i for i, p in enumerate(gt.track_ids)}
            for k, tid in enumerate(kt.track_ids):
                p = int(tid)
                if p not in people or p not in gcol:
                    continue
                ft, vv, jj = people[p]
                g = gcol[p]
                for t in np.flatnonzero(kt.valid[:, k]):
                    if not gt.present[t, g] or gt.area(t, g) < min_area or t_ref[t] < ft[0] or t_ref[t] > ft[-1]:
                        continue
                    i1 = int(np.clip(np.searchsorted(ft, t_ref[t]), 1, len(ft) - 1))
                    a = float(np.clip((t_ref[t] - ft[i1 - 1]) / max(ft[i1] - ft[i1 - 1], 1e-9), 0, 1))
                    V = (1 - a) * vv[i1 - 1] + a * vv[i1]
                    Jt = (1 - a) * jj[i1 - 1] + a * jj[i1]
                    xy = kt.xy[t, k].astype(np.float64)
                    if not np.isfinite(xy).all():
                        continue
                    h = float(gt.boxes[t, g, 3] - gt.boxes[t, g, 1])
                    anchor = reg0.apply(V, union)
                    depth = c.to_camera(anchor)[:, 2]
                    if (depth <= 0.05).any():
                        continue
                    out["V"].append(V.astype(np.float32))
                    out["cam"].append(ci)
                    out["xn"].append(c.pixels_to_lens(xy))
                    out["scale"].append(0.5 * (c.K[0, 0] + c.K[1, 1]) / (depth * h))
                    out["xy"].append(xy)
                    out["vis"].append(np.clip(kt.visibility[t, k] * kt.presence[t, k], 0, 1))
                    out["h"].append(h)
                    out["naive"].append(c.project(naive_points(model, V, Jt, union)))
                    out["src"].append(wi)
    if not out["V"]:
        raise UserError("no BlazePose detections on ground-truth tracks in these workspaces",
                        "run `mamma-kit track --backend gt` and `mamma-kit keypoints` on them first")
    s = lambda k: np.asarray(out[k])  # noqa: E731
    R = np.stack([c.R for c in cams])
    t = np.stack([c.t for c in cams])
    return Detections(union, s("V"), R, t, [c.K for c in cams], s("cam"), s("xn"), s("scale"), s("xy"), s("vis"),
                      s("h"), s("naive"), cams, s("src"))


def _design(det: Detections, k: int, cols: np.ndarray) -> np.ndarray:
    """Rows (2 N, S) of point k's ray equations over support columns ``cols`` (into union)."""
    R, t = det.R[det.cam_index], det.t[det.cam_index]  # (N, 3, 3), (N, 3)
    V = det.V[:, cols].astype(np.float64)  # (N, S, 3)
    Xc = np.einsum("nij,nsj->nsi", R, V) + t[:, None]  # (N, S, 3) camera frame
    x, y = det.xn[:, k, 0:1], det.xn[:, k, 1:2]
    sc = det.scale[:, k:k + 1]
    ex = (x * Xc[..., 2] - Xc[..., 0]) * sc
    ey = (y * Xc[..., 2] - Xc[..., 1]) * sc
    return np.stack([ex, ey], 1)  # (N, 2, S)


def regressed_errors(reg: KeypointRegressor, det: Detections, model) -> np.ndarray:
    """(N, 33) distance of the regressed true points projected to the detections, fraction
    of the box height."""
    X = reg.apply(det.V, det.union)
    px = np.stack([det.cams[c].project(X[i]) for i, c in enumerate(det.cam_index)])
    return np.linalg.norm(px - det.xy, axis=-1) / det.box_h[:, None]


def learn_regressor(det: Detections, model, reg0: KeypointRegressor | None = None, ridge: float = 3e-3,
                    rounds: int = 4, gm_scale: float = 2.5, provenance: dict | None = None) -> KeypointRegressor:
    """Learn the weights from detections (see module doc). ``ridge``: weight of |w - w0|^2
    relative to the mean squared residual row; ``gm_scale``: Geman-McClure scale in units
    of the robust residual scale (1.4826 x median)."""
    from scipy.optimize import lsq_linear

    reg0 = reg0 or initial_regressor(model)
    pos = {int(v): i for i, v in enumerate(det.union)}
    W = np.zeros_like(reg0.weights)
    sig = np.zeros(N_POINTS)
    stats = []
    for k in range(N_POINTS):
        cols = np.array([pos[int(v)] for v in reg0.ids[k]])
        A = _design(det, k, cols)  # (N, 2, S)
        vis = det.vis[:, k]
        use = vis > 0.05
        A, vis = A[use], vis[use]
        w0 = reg0.weights[k]
        w = w0.copy()
        rw = np.ones(len(A))
        n = len(A)
        for _ in range(rounds + 1):
            row_w = np.sqrt(vis * rw)[:, None, None]
            Aw = (A * row_w).reshape(2 * n, -1)
            mean_row = max(float((Aw ** 2).sum()) / max(2 * n, 1), 1e-12)
            lam = ridge * mean_row * 2 * n
            heavy = np.sqrt(1e4 * mean_row * 2 * n)
            M = np.vstack([Aw, np.sqrt(lam) * np.eye(len(w0)), heavy * np.ones((1, len(w0)))])
            b = np.r_[np.zeros(2 * n), np.sqrt(lam) * w0, heavy]
            w = lsq_linear(M, b, bounds=(0, np.inf), lsmr_tol="auto", max_iter=2000).x
            w = w / w.sum()
            r = np.linalg.norm(np.einsum("nas,s->na", A, w), axis=1)  # (n,) fraction of the box height
            s = 1.4826 * np.median(r[vis > 0.5]) if (vis > 0.5).sum() >= 10 else 1.4826 * np.median(r)
            c = gm_scale * max(s, 1e-4)
            rw = (c * c / (r * r + c * c)) ** 2
        w[w < 1e-4] = 0.0
        W[k] = w / w.sum()
        r = np.linalg.norm(np.einsum("nas,s->na", A, W[k]), axis=1)
        good = vis > 0.5
        sig[k] = 1.4826 * float(np.median(r[good] if good.sum() >= 10 else r))
        stats.append({"point": POINT_NAMES[k], "detections": int(n), "support": int((W[k] > 0).sum()),
                      "sigma_frac": round(sig[k], 5)})
    prov = dict(provenance or {})
    prov.update({"ridge": ridge, "rounds": rounds, "gm_scale": gm_scale, "points": stats})
    return KeypointRegressor(reg0.ids.copy(), W, sig, model.sha256, True, prov)


# ---- hands: MediaPipe's 21 points of each hand --------------------------------------------------

_FINGERS = ("thumb", "index", "middle", "ring", "pinky")
#: MediaPipe's hand points (keypoints/hands.py) on one hand of the skeleton: the wrist, then per finger
#: (thumb, index, middle, ring, pinky) its three joints (thumb: CMC, MCP, IP; the others MCP, PIP,
#: DIP = SMPL-X's finger1..3) and the fingertip vertex. Left hand, then right: 42 points.
HAND_ANCHORS = tuple(
    (("joint", f"{side}_wrist"),) + tuple(
        a for f in _FINGERS for a in ((("joint", f"{side}_{f}1"), ("joint", f"{side}_{f}2"),
                                       ("joint", f"{side}_{f}3"), ("vertex", f"{side}_{f}_tip"))))
    for side in ("left", "right"))
HAND_SUPPORT = 16  # vertices per hand point, all on the point's own finger segment (or palm)
# fraction of the person's box height: MediaPipe's points on the demo's hands where the model was sure
# (benchmarks/hand_keypoints.py: wrist 0.85 %, finger joints 1.62 % median; x 1.4826 / 1.18 for a
# robust standard deviation per point would be close to these)
HAND_SIGMA_FRAC = (0.012, 0.02)  # wrist, other points


def _hand_anchor(v: np.ndarray, J: np.ndarray, parents: np.ndarray, kind: str, name: str,
                 extra: dict | None) -> tuple[np.ndarray, list[int]]:
    """(3,) rest position of a hand point (rest vertices v (V, 3), joints J (55, 3)) and the joints
    whose vertices may carry it: a joint on its own segment and its parent's (the skin around it); a
    fingertip on the last segment."""
    if kind == "vertex":
        last = sk.JOINT_NAMES.index(name.replace("_tip", "3"))
        pos = v[extra[name]] if extra is not None else J[last]
        return pos, [last]
    j = sk.JOINT_NAMES.index(name)
    return J[j], [j, int(parents[j])]


def hand_regressor(model, support: int = HAND_SUPPORT) -> KeypointRegressor:
    """The 42 hand points (HAND_ANCHORS) as non-negative combinations of ``support`` vertices near
    each anchor whose dominant skinning joint is the anchor's segment (so a point bends with its own
    finger, not a neighbour's). Not learned: the hand model is sure of too few rendered hands to
    learn from (benchmarks/hand_keypoints.py: 9-14 %), so the weights only reproduce the anchors."""
    v = model.v_template.numpy().astype(np.float64)
    J = model.J_template.numpy().astype(np.float64)
    parents = model.parents.numpy()
    dominant = model.weights_dense.numpy().argmax(1)
    extra = None if model.extra_joint_ids is None else dict(zip(sk.EXTRA_JOINT_NAMES, model.extra_joint_ids))
    anchors = [a for side in HAND_ANCHORS for a in side]
    ids = np.zeros((len(anchors), support), np.int64)
    W = np.zeros((len(anchors), support))
    for k, (kind, name) in enumerate(anchors):
        a, joints = _hand_anchor(v, J, parents, kind, name, extra)
        cand = np.flatnonzero(np.isin(dominant, joints))
        if len(cand) < support:  # a coarse body: fall back to the nearest vertices
            cand = np.arange(len(v))
        near = cand[np.argsort(np.linalg.norm(v[cand] - a, axis=1))[:support]]
        ids[k] = np.sort(near)
        W[k] = anchor_weights(v[ids[k]], a)
    sig = np.array([HAND_SIGMA_FRAC[0] if name.endswith("_wrist") else HAND_SIGMA_FRAC[1] for _, name in anchors])
    return KeypointRegressor(ids, W, sig, model.sha256, False,
                             {"made_by": "hand_regressor (anchors on the hand's joints and fingertips, not learned)"})


def stacked(*regs: KeypointRegressor) -> KeypointRegressor:
    """One regressor whose points are those of ``regs`` in order (supports padded with zero weights)."""
    S = max(r.ids.shape[1] for r in regs)
    pad = lambda a, fill: np.concatenate([a, np.repeat(fill, S - a.shape[1], 1)], 1)  # noqa: E731
    ids = np.concatenate([pad(r.ids, r.ids[:, :1]) for r in regs])
    W = np.concatenate([pad(r.weights, np.zeros_like(r.weights[:, :1])) for r in regs])
    return KeypointRegressor(ids, W, np.concatenate([r.sigma_frac for r in regs]), regs[0].body_sha256,
                             all(r.learned for r in regs), {"stacked": [r.provenance for r in regs]})
