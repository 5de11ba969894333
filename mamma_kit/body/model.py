"""Body models in SMPL-X layout: the embedded open body and real SMPL-X .npz files.

``load_body_model(spec)`` reads either through ONE code path: the open body is stored in
the SMPL-X key layout (v_template, f, weights, J_regressor, kintree_table, shapedirs,
posedirs, hands_mean{l,r}, ...) plus a few ``mk_*`` keys of its own (landmark ids, extra
keypoint ids, provenance). Files are read with ``np.load(allow_pickle=False)`` and only
the keys needed are touched, so object arrays elsewhere in a file do no harm.

Conventions (identical to the ``smplx`` package with ``flat_hand_mean=True``,
``use_pca=False``): the canonical frame is Y up, facing +Z; hand poses are absolute
axis-angle rotations (zero = flat hand), the file's ``hands_mean`` is kept only for
reference; shape uses the first 16 components, expression the 10 at columns 300..309 of
``shapedirs`` when the file has them (SMPL-X v1.1), else columns 10..19 (v1.0 files with
10 + 10 components), else none.
"""

from __future__ import annotations

import functools
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from mamma_kit.body import skeleton as sk
from mamma_kit.body.landmarks import LANDMARK_COUNT, LandmarkSet, landmark_parts_for, landmark_set_fps
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import sha256_file

DATA_DIR = Path(__file__).resolve().parent / "data"
OPEN_BODY_FILE = DATA_DIR / "open_body.npz"
OPEN_BODY_NAME = "open-anny"

#: Keys every SMPL-X-layout file must have (facts of the format).
REQUIRED_KEYS = ("v_template", "f", "weights", "J_regressor", "kintree_table", "shapedirs")
#: Weights at or below this are dropped from the sparse skinning table.
SKIN_EPS = 1e-6
MAX_WEIGHTS_PER_VERTEX = 16


@dataclass(eq=False)
class BodyModel:
    """A body model in SMPL-X layout, float32 torch tensors on the CPU (numpy views via ``.np``).
    load_body_model caches and shares instances: treat the tensors as read-only.

    V vertices, F faces, B = 16 shape components, E expression components (10 or 0),
    K skinning weights kept per vertex, J = 55 joints.

    v_template: (V, 3) rest vertices in the canonical frame (Y up, facing +Z), metres.
    faces: (F, 3) int64 triangle vertex ids.
    shapedirs: (V, 3, B) shape displacements per unit beta.
    exprdirs: (V, 3, E) expression displacements, or None when the model has none.
    posedirs: (V, 3, 486) pose-corrective displacements per entry of (R_j - I) for joints
        1..54 (SMPL-X layout), or None when the file's are all zero (the open body).
    J_regressor: (J, V) rest joints = J_regressor @ shaped vertices.
    skin_idx, skin_w: (V, K) int64 joint ids and float32 weights (zero-padded) of the
        sparse skinning table; weights_dense (V, J) is the same table dense.
    parents: (J,) int64 parent joint (-1 for the pelvis); joint_names: J names.
    J_template: (J, 3), J_shapedirs: (J, 3, B), J_exprdirs: (J, 3, E) or None: the joint
        regressor applied to the template and the blend shapes (so joints never touch V).
    vertex_part: (V,) int64 indices into skeleton.PART_NAMES (dominant skinning part).
    extra_joint_ids: (21,) vertex ids of skeleton.EXTRA_JOINT_NAMES, or None (real SMPL-X:
        use smplx's own table).
    hands_mean: (2, 45) the file's mean hand pose (left, right), kept for reference only.
    landmarks: the 512-landmark set (baked for the open body, FPS for other models).
    """

    name: str
    sha256: str
    path: Path | None
    gender: str
    v_template: torch.Tensor
    faces: torch.Tensor
    shapedirs: torch.Tensor
    exprdirs: torch.Tensor | None
    posedirs: torch.Tensor | None
    J_regressor: torch.Tensor
    skin_idx: torch.Tensor
    skin_w: torch.Tensor
    weights_dense: torch.Tensor
    parents: torch.Tensor
    joint_names: list[str]
    J_template: torch.Tensor
    J_shapedirs: torch.Tensor
    J_exprdirs: torch.Tensor | None
    vertex_part: np.ndarray
    extra_joint_ids: np.ndarray | None
    hands_mean: np.ndarray
    landmarks: LandmarkSet
    provenance: str = ""
    is_open_body: bool = False
    _cache: dict = field(default_factory=dict, repr=False)

    # ---- sizes -------------------------------------------------------------------------
    @property
    def num_vertices(self) -> int:
        return int(self.v_template.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def num_joints(self) -> int:
        return int(self.parents.shape[0])

    @property
    def num_betas(self) -> int:
        return int(self.shapedirs.shape[-1])

    @property
    def num_expression(self) -> int:
        return 0 if self.exprdirs is None else int(self.exprdirs.shape[-1])

    @property
    def landmark_ids(self) -> np.ndarray:
        """(L,) int64 vertex ids of the landmarks."""
        return self.landmarks.ids

    @property
    def landmark_parts(self) -> np.ndarray:
        """(L,) int64 landmark part labels (indices into skeleton.LANDMARK_PART_NAMES)."""
        return self.landmarks.part

    @property
    def vertex_parts(self) -> np.ndarray:
        """(V,) int64 body part of every vertex, indices into ``part_names``."""
        return self.vertex_part

    @property
    def part_names(self) -> list[str]:
        """Names of the per-vertex parts (skeleton.PART_NAMES)."""
        return list(sk.PART_NAMES)

    @property
    def levels(self) -> list[np.ndarray]:
        """Joint ids per tree depth (forward kinematics batches one level at a time)."""
        if "levels" not in self._cache:
            self._cache["levels"] = sk.tree_levels(self.parents.numpy())
        return self._cache["levels"]

    @property
    def np(self) -> "_NumpyViews":
        """Numpy views (no copies) of the model's tensors, e.g. ``model.np.v_template``."""
        return _NumpyViews(self)

    def summary(self) -> dict:
        """JSON-able description (``mamma-kit body info``)."""
        return {"name": self.name, "sha256": self.sha256, "path": str(self.path) if self.path else None,
                "gender": self.gender, "open_body": self.is_open_body, "vertices": self.num_vertices,
                "faces": self.num_faces, "joints": self.num_joints, "landmarks": len(self.landmarks),
                "landmark_source": self.landmarks.source, "shape_components": self.num_betas,
                "expression_components": self.num_expression, "pose_correctives": self.posedirs is not None,
                "skin_weights_per_vertex": int(self.skin_idx.shape[1])}

    def with_landmarks(self, landmarks: LandmarkSet) -> "BodyModel":
        """A copy using another landmark set (e.g. one read by landmarks.load_landmark_definition)."""
        if len(landmarks.ids) and (landmarks.ids.min() < 0 or landmarks.ids.max() >= self.num_vertices):
            raise UserError(f"landmark ids outside 0..{self.num_vertices - 1} for body model {self.name}",
                            "use a landmark definition made for this body model")
        return replace(self, landmarks=landmarks, _cache={})

    # ---- cached derived objects (built on first use) -----------------------------------
    def skin_blocks(self):
        """Vertex groups for block-sparse skinning of the full mesh (lbs.SkinBlocks), cached."""
        from mamma_kit.body.lbs import SkinBlocks

        if "skin_blocks" not in self._cache:
            self._cache["skin_blocks"] = SkinBlocks.build(self.weights_dense, self.vertex_part)
        return self._cache["skin_blocks"]

    def restricted(self, vertex_ids: np.ndarray | None = None):
        """Per-vertex-set data for restricted LBS (see lbs.RestrictedBody); default: the landmarks.

        Cached per id set, so calling it every iteration is free.
        """
        from mamma_kit.body.lbs import RestrictedBody

        ids = self.landmarks.ids if vertex_ids is None else np.asarray(vertex_ids, dtype=np.int64)
        key = ("restricted", ids.tobytes())
        if key not in self._cache:
            self._cache[key] = RestrictedBody.build(self, ids)
        return self._cache[key]

    @property
    def proxy(self):
        """The low-resolution closed proxy mesh (see proxy.ProxyMesh), built on first use."""
        if "proxy" not in self._cache:
            from mamma_kit.body.proxy import build_proxy

            self._cache["proxy"] = build_proxy(self)
        return self._cache["proxy"]


class _NumpyViews:
    def __init__(self, model: BodyModel):
        self._m = model

    def __getattr__(self, name: str):
        v = getattr(self._m, name)
        return v.numpy() if isinstance(v, torch.Tensor) else v


# ---- loading ------------------------------------------------------------------------------

def resolve_body_model_path(spec: str | Path = "open", gender: str = "neutral") -> Path:
    """The file a ``--body-model`` spec points at: "open" (embedded), a .npz file, or a
    folder holding SMPLX_{NEUTRAL,MALE,FEMALE}.npz (picked by ``gender``)."""
    if str(spec).lower() in ("open", "", "default"):
        if not OPEN_BODY_FILE.is_file():
            raise UserError(f"the embedded open body is missing ({OPEN_BODY_FILE})",
                            "reinstall mamma-kit, or re-bake it: python -m mamma_kit.body.bake")
        return OPEN_BODY_FILE
    p = Path(spec).expanduser()
    if p.is_dir():
        g = gender.upper()
        for cand in (p / f"SMPLX_{g}.npz", p / "smplx" / f"SMPLX_{g}.npz"):
            if cand.is_file():
                return cand
        if any(p.glob(f"SMPLX_{g}.pkl")) or any(p.glob(f"smplx/SMPLX_{g}.pkl")):
            _refuse_pickle(next(iter(list(p.glob(f"SMPLX_{g}.pkl")) + list(p.glob(f"smplx/SMPLX_{g}.pkl")))))
        raise UserError(f"no SMPLX_{g}.npz in folder {p}",
                        "pass the .npz file itself, or a folder with SMPLX_NEUTRAL/MALE/FEMALE.npz")
    if not p.exists():
        raise UserError(f"body model not found: {p}",
                        "pass --body-model open (embedded) or the path of your SMPLX_*.npz file")
    if p.suffix.lower() in (".pkl", ".pickle"):
        _refuse_pickle(p)
    return p


def _refuse_pickle(p: Path):
    raise UserError(
        f"body model {p} is a pickled file, which mamma-kit refuses to load (pickles can run code)",
        "use the SMPLX_*.npz files from the SMPL-X download (the models_smplx_v1_1 zip has them), or convert once "
        "in a trusted Python: d = pickle.load(open(PKL, 'rb'), encoding='latin1'); np.savez(NPZ, **{k: "
        "np.asarray(v.toarray() if hasattr(v, 'toarray') else v) for k, v in d.items() if k in ('v_template', 'f', "
        "'weights', 'J_regressor', 'kintree_table', 'shapedirs', 'posedirs', 'hands_meanl', 'hands_meanr')})")


def load_body_model(spec: str | Path = "open", gender: str = "neutral") -> BodyModel:
    """Load a body model: ``"open"`` (the embedded open body), an SMPL-X .npz file, or a
    folder with SMPLX_{GENDER}.npz. Raises UserError for missing, pickled or malformed files.

    Loaded models are cached per (file, mtime, size), so calling this repeatedly is cheap.
    """
    path = resolve_body_model_path(spec, gender)
    st = path.stat()
    return _load_cached(str(path.resolve()), st.st_mtime_ns, st.st_size, gender.lower())


@functools.lru_cache(maxsize=4)
def _load_cached(path: str, mtime_ns: int, size: int, gender: str) -> BodyModel:
    return read_body_model_file(Path(path), gender)


def _read_keys(path: Path) -> dict[str, np.ndarray]:
    """The needed arrays of an SMPL-X-layout .npz, touching no other key."""
    if not zipfile.is_zipfile(path):
        try:
            head = path.read_bytes()[:2]
        except OSError as e:
            raise UserError(f"cannot read body model {path} ({e})", "check the file permissions") from None
        if head[:1] == b"\x80":
            _refuse_pickle(path)
        raise UserError(f"body model {path} is not an .npz file",
                        "pass an SMPL-X .npz model (SMPLX_NEUTRAL.npz etc.) or --body-model open")
    wanted = REQUIRED_KEYS + ("posedirs", "hands_meanl", "hands_meanr", "mk_name", "mk_landmark_ids",
                              "mk_landmark_parts", "mk_extra_joint_ids", "mk_provenance", "mk_gender")
    out: dict[str, np.ndarray] = {}
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in REQUIRED_KEYS if k not in z.files]
            if missing:
                raise UserError(f"body model {path} lacks the SMPL-X keys {missing} (it has {sorted(z.files)[:12]})",
                                "pass an SMPL-X model file (SMPLX_NEUTRAL.npz etc.) or --body-model open")
            for k in wanted:
                if k in z.files:
                    try:
                        out[k] = z[k]
                    except ValueError as e:
                        if "pickle" in str(e).lower():
                            raise UserError(f"body model {path} stores '{k}' as a pickled object",
                                            "re-save that key as a plain numeric array (np.savez)") from None
                        raise
    except UserError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise UserError(f"body model {path} is corrupt or unreadable ({e})", "download or bake it again") from None
    return out


def _sparse_skinning(weights_vj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dense (V, J) weights -> (V, K) joint ids and weights of the non-zero entries (K = most
    per vertex, zero-padded; capped at MAX_WEIGHTS_PER_VERTEX with renormalisation)."""
    w = np.where(weights_vj > SKIN_EPS, weights_vj, 0.0)
    k = int(max(1, min(MAX_WEIGHTS_PER_VERTEX, (w > 0).sum(1).max())))
    order = np.argsort(-w, axis=1, kind="stable")[:, :k]
    ws = np.take_along_axis(w, order, axis=1)
    if (w > 0).sum(1).max() > k:  # only when capped: keep the mass of what was dropped
        ws = ws * (w.sum(1, keepdims=True) / np.maximum(ws.sum(1, keepdims=True), 1e-12))
    order = np.where(ws > 0, order, 0)
    return order.astype(np.int64), ws.astype(np.float32)


def vertex_parts_from_weights(weights_vj: np.ndarray) -> np.ndarray:
    """(V,) part ids (skeleton.PART_NAMES): the part with the largest summed skinning weight."""
    mass_vp = np.zeros((weights_vj.shape[0], len(sk.PART_NAMES)))
    np.add.at(mass_vp.T, sk.JOINT_PART, weights_vj.T)
    return mass_vp.argmax(1).astype(np.int64)


def read_body_model_file(path: Path, gender: str = "neutral") -> BodyModel:
    """Read and validate an SMPL-X-layout .npz (our open body or a real SMPL-X file)."""

    d = _read_keys(path)

    def bad(msg: str):
        return UserError(f"body model {path}: {msg}", "pass an SMPL-X model file (SMPLX_NEUTRAL.npz etc.) "
                                                      "or --body-model open")

    v = np.asarray(d["v_template"], dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 4:
        raise bad(f"v_template has shape {v.shape}, expected (V, 3)")
    V = v.shape[0]
    faces = np.asarray(d["f"]).astype(np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= V:
        raise bad(f"faces 'f' have shape {faces.shape} or ids outside 0..{V - 1}")
    kt = np.asarray(d["kintree_table"]).astype(np.int64)
    if kt.ndim != 2 or kt.shape[0] != 2 or kt.shape[1] != sk.NUM_JOINTS:
        raise bad(f"kintree_table has shape {kt.shape}, expected (2, 55): not an SMPL-X model")
    parents = kt[0].copy()
    parents[0] = -1
    if not np.array_equal(parents, sk.PARENTS):
        raise bad("kintree_table is not the SMPL-X kinematic tree")
    W = np.asarray(d["weights"], dtype=np.float64)
    if W.shape != (V, sk.NUM_JOINTS):
        raise bad(f"weights have shape {W.shape}, expected ({V}, 55)")
    Jr = d["J_regressor"]
    if Jr.dtype == object or Jr.shape != (sk.NUM_JOINTS, V):
        raise bad(f"J_regressor has shape {Jr.shape}, expected (55, {V})")
    Jr = np.asarray(Jr, dtype=np.float64)
    S = np.asarray(d["shapedirs"])
    if S.ndim != 3 or S.shape[:2] != (V, 3):
        raise bad(f"shapedirs has shape {S.shape}, expected ({V}, 3, N)")
    nS = S.shape[2]
    if nS >= 300 + sk.NUM_EXPRESSION:  # SMPL-X v1.1: 300 shape + 100 expression components
        shape = S[:, :, :min(sk.NUM_BETAS, 300)]
        expr = S[:, :, 300:300 + sk.NUM_EXPRESSION]
    elif nS >= 10 + sk.NUM_EXPRESSION:  # SMPL-X v1.0: 10 shape + 10 expression components
        shape, expr = S[:, :, :10], S[:, :, 10:20]
    else:
        shape, expr = S[:, :, :sk.NUM_BETAS], None
    shape = np.asarray(shape, dtype=np.float32)
    if shape.shape[2] < sk.NUM_BETAS:  # pad: extra betas have no effect, the vector keeps 16 entries
        shape = np.concatenate([shape, np.zeros((V, 3, sk.NUM_BETAS - shape.shape[2]), np.float32)], 2)
    if expr is not None:
        expr = np.asarray(expr, dtype=np.float32)
        if not np.any(expr):
            expr = None
    posedirs = None
    if "posedirs" in d:
        P = d["posedirs"]
        if P.shape != (V, 3, 9 * (sk.NUM_JOINTS - 1)):
            raise bad(f"posedirs has shape {P.shape}, expected ({V}, 3, 486)")
        if np.any(P):
            posedirs = np.asarray(P, dtype=np.float32)
    for k in ("v_template", "weights", "J_regressor"):
        if not np.all(np.isfinite(d[k])):
            raise bad(f"{k} holds NaN or inf")

    skin_idx, skin_w = _sparse_skinning(W)
    hands_mean = np.zeros((2, 45))
    for i, k in enumerate(("hands_meanl", "hands_meanr")):
        if k in d and np.asarray(d[k]).size == 45:
            hands_mean[i] = np.asarray(d[k], dtype=np.float64).ravel()
    vertex_part = vertex_parts_from_weights(W)

    is_open = "mk_name" in d
    name = str(d["mk_name"]) if is_open else path.stem
    if is_open and "mk_gender" in d:
        gender = str(d["mk_gender"])
    elif not is_open:
        stem = path.stem.upper()
        for g in ("NEUTRAL", "FEMALE", "MALE"):
            if g in stem:
                gender = g.lower()
                break
    extra_ids = np.asarray(d["mk_extra_joint_ids"], dtype=np.int64) if "mk_extra_joint_ids" in d else None

    if "mk_landmark_ids" in d:
        ids = np.asarray(d["mk_landmark_ids"], dtype=np.int64)
        part = (np.asarray(d["mk_landmark_parts"], dtype=np.int64) if "mk_landmark_parts" in d
                else landmark_parts_for(vertex_part, ids))
        if len(ids) != LANDMARK_COUNT or ids.min() < 0 or ids.max() >= V or len(part) != len(ids):
            raise bad("mk_landmark_ids are not 512 vertex ids")
        landmarks = LandmarkSet(ids, part, source="baked")
    else:
        landmarks = landmark_set_fps(v, W, vertex_part)

    v32 = v.astype(np.float32)
    Jr32 = Jr.astype(np.float32)
    J_template = Jr @ v
    J_shapedirs = np.einsum("jv,vcb->jcb", Jr, shape.astype(np.float64))
    J_exprdirs = None if expr is None else np.einsum("jv,vcb->jcb", Jr, expr.astype(np.float64))
    t = torch.from_numpy
    return BodyModel(
        name=name, sha256=sha256_file(path), path=path, gender=gender,
        v_template=t(v32), faces=t(faces), shapedirs=t(np.ascontiguousarray(shape)),
        exprdirs=None if expr is None else t(np.ascontiguousarray(expr)),
        posedirs=None if posedirs is None else t(posedirs),
        J_regressor=t(Jr32), skin_idx=t(skin_idx), skin_w=t(skin_w),
        weights_dense=t(W.astype(np.float32)), parents=t(parents), joint_names=list(sk.JOINT_NAMES),
        J_template=t(J_template.astype(np.float32)), J_shapedirs=t(J_shapedirs.astype(np.float32)),
        J_exprdirs=None if J_exprdirs is None else t(J_exprdirs.astype(np.float32)),
        vertex_part=vertex_part, extra_joint_ids=extra_ids, hands_mean=hands_mean, landmarks=landmarks,
        provenance=str(d["mk_provenance"]) if "mk_provenance" in d else "", is_open_body=is_open,
    )
