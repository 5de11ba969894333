"""Blender opens the exports: the glTF and BVH imported by Blender's own importers (bpy, Blender as
a Python module), and every fitted joint compared with the imported armature's bones.

bpy pins its Python and weighs hundreds of MB, so it lives in a venv of its own, not the project's:

    python3.11 -m venv /tmp/bpyenv && /tmp/bpyenv/bin/pip install bpy
    .venv/bin/mamma-kit export WS --format gltf --out /tmp/bl/capture.glb
    .venv/bin/mamma-kit export WS --format bvh --out /tmp/bl
    /tmp/bpyenv/bin/python benchmarks/blender_import.py WS /tmp/bl

It prints what Blender made of each file (armatures, meshes, cameras, the action's frames) and the
largest distance between a fitted joint and the imported bone's head over every person and frame.
"""

from __future__ import annotations

import sys
from pathlib import Path

import bpy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from mamma_kit.body.skeleton import JOINT_NAMES  # noqa: E402  (numpy only: no torch in Blender's venv)


def main() -> None:
    ws, folder = Path(sys.argv[1]), Path(sys.argv[2])
    people = {int(p.stem.split("_")[1]): np.load(p) for p in sorted((ws / "smplx").glob("person_*.npz"))}
    bpy.ops.wm.read_factory_settings(use_empty=True)
    print(f"Blender {bpy.app.version_string}")
    assert bpy.ops.import_scene.gltf(filepath=str(folder / "capture.glb")) == {"FINISHED"}
    objs = list(bpy.data.objects)
    kinds = {k: sorted(o.name for o in objs if o.type == k) for k in ("ARMATURE", "MESH", "CAMERA")}
    action = bpy.data.actions[0]
    print(f"glTF: {len(kinds['ARMATURE'])} armature, {len(kinds['MESH'])} meshes, {len(kinds['CAMERA'])} cameras, "
          f"action '{action.name}' over frames {action.frame_range[0]:.1f}-{action.frame_range[1]:.1f}")
    arm = next(o for o in objs if o.type == "ARMATURE")
    scene = bpy.context.scene
    t0 = min(float(d["frame_times"][0]) for d in people.values())
    worst, n = 0.0, 0
    for k, d in people.items():
        bones = [arm.pose.bones[f"person{k}/{j}"] for j in JOINT_NAMES]
        for f, t in enumerate(d["frame_times"]):
            frame = (t - t0) * scene.render.fps  # the importer keys seconds x the scene's rate
            scene.frame_set(int(np.floor(frame)), subframe=float(frame - np.floor(frame)))
            heads = np.array([tuple(arm.matrix_world @ b.head) for b in bones])
            worst = max(worst, float(np.abs(heads - d["joints"][f]).max()))
            n += 1
    print(f"glTF joints in Blender: at most {worst * 1e3:.4f} mm from the fit's over {n} person-frames")
    for k in people:
        bvh = folder / f"person_{k}.bvh"
        if bvh.is_file():
            before = {o.name for o in bpy.data.objects}
            bpy.ops.import_anim.bvh(filepath=str(bvh), global_scale=0.01)
            new = next(o for o in bpy.data.objects if o.name not in before)
            print(f"BVH person {k}: {len(new.data.bones)} bones, frames "
                  f"{bpy.data.actions[-1].frame_range[0]:.0f}-{bpy.data.actions[-1].frame_range[1]:.0f}")


if __name__ == "__main__":
    main()
