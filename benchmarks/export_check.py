"""Exports of fitted workspaces: time and size per format, and how faithfully the glTF plays the fit.

For each workspace (one with smplx/person_<k>.npz, e.g. the demo's or the real recording's after
`capture-to-smplx`), every format is written to a temporary folder (`mamma_kit.export.run`), and
the glTF is read back as a viewer plays it (export/gltf_read.py): each person's 55 joints at every
fitted frame against the fit's joints, and the skinned mesh (glTF's four weights per vertex)
against the fit's mesh at up to 20 frames per person.

    python benchmarks/export_check.py /work/bench/gate/new /work/bench/speed_new/ws
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from mamma_kit.export.motion import Z_UP_TO_Y_UP
from mamma_kit.export.run import FORMATS, export_workspace

MESH_FRAMES = 20


def gltf_errors(glb: Path, people, model) -> tuple[float, np.ndarray]:
    """Largest joint error (m) over every person and frame; vertex errors (m, frames x V) at sampled frames."""
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.export.gltf_read import GltfScene

    scene = GltfScene(glb)
    t0 = min(r.frame_times[0] for _, r in people)
    worst, verts = 0.0, []
    for k, r in people:
        ids = [scene.node_id[f"person{k}/{j}"] for j in model.joint_names]
        node = scene.gltf.nodes[scene.node_id[f"person{k}/body"]]
        skin, prim = scene.gltf.skins[node.skin], scene.gltf.meshes[node.mesh].primitives[0]
        ibm = scene.array(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        rest = np.c_[scene.array(prim.attributes.POSITION), np.ones(model.num_vertices)]
        J, W = scene.array(prim.attributes.JOINTS_0), scene.array(prim.attributes.WEIGHTS_0)
        sampled = set(np.linspace(0, r.num_frames - 1, min(MESH_FRAMES, r.num_frames)).astype(int).tolist())
        for f in range(r.num_frames):
            world = scene.world(r.frame_times[f] - t0)
            xyz = np.array([world[i][:3, 3] for i in ids]) @ Z_UP_TO_Y_UP
            worst = max(worst, float(np.abs(xyz - r.joints[f]).max()))
            if f in sampled:
                M = np.stack([world[j] @ ibm[i] for i, j in enumerate(skin.joints)])
                skinned = np.einsum("vk,vkab,vb->va", W, M[J], rest)[:, :3] @ Z_UP_TO_Y_UP
                ref, _ = pose_mesh_np(model, r.params(f))
                verts.append(np.linalg.norm(skinned - ref[0], axis=1))
    return worst, np.stack(verts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("workspaces", nargs="+", type=Path)
    args = ap.parse_args()
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.smplxfile import read_smplx_result
    from mamma_kit.core.workspace import Workspace

    for root in args.workspaces:
        ws = Workspace(root)
        people = [(int(p.stem.split("_")[1]), read_smplx_result(p)) for p in ws.person_files()]
        model = load_body_model(ws.load_capture().body_model, people[0][1].gender)
        frames = sum(r.num_frames for _, r in people)
        print(f"{root}: {len(people)} persons, {frames} person-frames, body {model.name}")
        print(f"  {'format':8s} {'seconds':>8s} {'MB':>7s}  files")
        with tempfile.TemporaryDirectory() as tmp:
            for fmt in FORMATS:
                out = Path(tmp) / fmt
                t = time.perf_counter()
                res = export_workspace(ws, fmt, out=out)
                secs = time.perf_counter() - t
                size = sum(Path(f["path"]).stat().st_size for f in res["files"]) / 1e6
                print(f"  {fmt:8s} {secs:8.2f} {size:7.2f}  {', '.join(Path(f['path']).name for f in res['files'])}")
            worst, err = gltf_errors(Path(tmp) / "gltf" / "capture.glb", people, model)
        print(f"  glTF played back: joints at most {worst * 1e6:.1f} µm from the fit's over every frame; mesh "
              f"(four weights per vertex) median {np.median(err) * 1e3:.3f} mm, 99th percentile "
              f"{np.percentile(err, 99) * 1e3:.2f} mm, worst {err.max() * 1e3:.1f} mm from the fit's")
        many = int(((model.weights_dense > 0).sum(1) > 4).sum())
        worst_part = model.part_names[model.vertex_parts[int(err.max(0).argmax())]]
        print(f"  vertices with more than four skin weights: {many} of {model.num_vertices}; the worst one "
              f"is on the {worst_part.replace('_', ' ')}")


if __name__ == "__main__":
    main()
