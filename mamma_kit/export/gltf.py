"""glTF 2.0 (.glb, or .gltf with the data inside): every fitted person as a skinned mesh on its
skeleton, animated at the fit's frame times, with the calibrated cameras and the floor, for
Blender, three.js, Unity and Unreal. Written with pygltflib.

Scene graph: a node ``world`` turns mamma-kit's Z-up world into glTF's Y-up (``Z_UP_TO_Y_UP``);
under it each person's skeleton (nodes named ``person<k>/<joint>``: the root's translation and
rotation place the body, every joint's rotation is its SMPL-X pose), the cameras
(``camera/<name>``, glTF's -Z view axis onto OpenCV's +Z) and the floor. The mesh nodes are the
scene's other roots (glTF ignores a skinned mesh node's own transform).

What glTF cannot hold: pose-corrective blend shapes and expressions (a real SMPL-X's mesh moves a
little differently from what these skin weights alone give; the joints are exact), and more than
four skin weights per vertex (the four largest are kept, renormalised, as three.js reads them).
A person absent for a while (gaps in their fitted frames) is scaled to nothing there (a step
channel), not slid across the gap.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as g

from mamma_kit.export.motion import Z_UP_TO_Y_UP, SkeletonMotion
from mamma_kit.export.motion import skeleton_motion as make_motion

SKIN_WEIGHTS = 4
FLOOR_MARGIN_M = 1.5
FRUSTUM_DEPTH_M = 0.3  # the drawn view pyramid of each camera
GAP_FRAMES = 1.5  # a step between fitted frames longer than this many frame periods is a gap


class _Blob:
    """One binary buffer, a buffer view and accessor per array."""

    def __init__(self, gltf: g.GLTF2):
        self.gltf, self.parts, self.size = gltf, [], 0

    def add(self, a: np.ndarray, kind: str, target: int | None = None, bounds: bool = False) -> int:
        a = np.ascontiguousarray(a)
        comp = {np.dtype(np.float32): g.FLOAT, np.dtype(np.uint16): g.UNSIGNED_SHORT,
                np.dtype(np.uint32): g.UNSIGNED_INT}[a.dtype]
        pad = (-self.size) % 4
        self.parts.append(b"\0" * pad)
        self.size += pad
        data = a.tobytes()
        self.gltf.bufferViews.append(g.BufferView(buffer=0, byteOffset=self.size, byteLength=len(data), target=target))
        self.parts.append(data)
        self.size += len(data)
        flat = a.reshape(len(a), -1)
        acc = g.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=comp, count=len(a), type=kind)
        if bounds:
            acc.min, acc.max = flat.min(0).tolist(), flat.max(0).tolist()
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def _quat(R_33: np.ndarray) -> list[float]:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R_33).as_quat().tolist()


def _material(gltf: g.GLTF2, name: str, rgb, roughness: float = 0.8) -> int:
    gltf.materials.append(g.Material(name=name, pbrMetallicRoughness=g.PbrMetallicRoughness(
        baseColorFactor=[*map(float, rgb), 1.0], metallicFactor=0.0, roughnessFactor=roughness), doubleSided=True))
    return len(gltf.materials) - 1


def _body_mesh(gltf: g.GLTF2, blob: _Blob, model, betas: np.ndarray, name: str, material: int) -> int:
    """The person's shaped rest mesh (canonical frame) with its four largest skin weights per vertex."""
    import trimesh

    v = model.np.v_template.astype(np.float64) + np.einsum("vcb,b->vc", model.np.shapedirs.astype(np.float64),
                                                           betas[:model.num_betas])
    faces = model.np.faces.astype(np.uint32)
    normals = trimesh.Trimesh(v, faces, process=False).vertex_normals
    W = model.weights_dense.numpy()
    top = np.argsort(-W, axis=1, kind="stable")[:, :SKIN_WEIGHTS]
    w = np.take_along_axis(W, top, 1)
    w /= w.sum(1, keepdims=True)
    top[w == 0] = 0  # glTF: an unused slot names joint 0
    attrs = g.Attributes(POSITION=blob.add(v.astype(np.float32), g.VEC3, g.ARRAY_BUFFER, bounds=True),
                         NORMAL=blob.add(normals.astype(np.float32), g.VEC3, g.ARRAY_BUFFER),
                         JOINTS_0=blob.add(top.astype(np.uint16), g.VEC4, g.ARRAY_BUFFER),
                         WEIGHTS_0=blob.add(w.astype(np.float32), g.VEC4, g.ARRAY_BUFFER))
    prim = g.Primitive(attributes=attrs, indices=blob.add(faces.reshape(-1), g.SCALAR, g.ELEMENT_ARRAY_BUFFER),
                       material=material)
    gltf.meshes.append(g.Mesh(name=name, primitives=[prim]))
    return len(gltf.meshes) - 1


def _visibility_keys(times_t: np.ndarray, t0: float, t_end: float, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Step keys (times, scale 0 or 1) that hide a person outside their fitted frames; each switch
    half a frame away from a fitted frame, so sampling at a frame's own time never lands on one."""
    half = 0.5 / fps
    gaps = np.flatnonzero(np.diff(times_t) > GAP_FRAMES / fps)
    starts = np.r_[times_t[0], times_t[gaps + 1]] - half
    ends = np.r_[times_t[gaps], times_t[-1]] + half
    keys = [(t0, 0.0)] if starts[0] > t0 else []
    for a, b in zip(starts, ends):
        keys.append((max(a, t0), 1.0))
        if b < t_end:
            keys.append((b, 0.0))
    t, s = np.array(keys).T
    return (t - t0).astype(np.float32), s


class _Animation:
    """One glTF animation: every channel of every person on one timeline."""

    def __init__(self, blob: _Blob):
        self.blob, self.anim, self.inputs = blob, g.Animation(name="capture"), {}

    def channel(self, node: int, path: str, times: np.ndarray, values: np.ndarray, kind: str,
                interpolation: str = g.ANIM_LINEAR) -> None:
        key = times.tobytes()
        if key not in self.inputs:  # one time accessor per distinct timeline
            self.inputs[key] = self.blob.add(times.astype(np.float32), g.SCALAR, bounds=True)
        self.anim.samplers.append(g.AnimationSampler(input=self.inputs[key], interpolation=interpolation,
                                                     output=self.blob.add(values.astype(np.float32), kind)))
        self.anim.channels.append(g.AnimationChannel(sampler=len(self.anim.samplers) - 1,
                                                     target=g.AnimationChannelTarget(node=node, path=path)))


def _add_person(gltf: g.GLTF2, blob: _Blob, anim: _Animation, world: int, pid: int, model, result,
                motion: SkeletonMotion, t0: float, t_end: float, colour) -> None:
    base = len(gltf.nodes)
    T = motion.num_frames
    quats = motion.quaternions_tj4()
    times = (motion.times_t - t0).astype(np.float32)
    for j, name in enumerate(motion.names):
        gltf.nodes.append(g.Node(name=f"person{pid}/{name}", translation=motion.offset_tj3[0, j].tolist(),
                                 rotation=quats[0, j].tolist()))
    for j, par in enumerate(motion.parents):
        (gltf.nodes[world] if par < 0 else gltf.nodes[base + par]).children.append(base + j)
    moving = np.flatnonzero(np.abs(motion.offset_tj3 - motion.offset_tj3[:1]).max((0, 2)) > 1e-6)
    for j in range(len(motion.names)):
        anim.channel(base + j, "rotation", times, quats[:, j], g.VEC4)
    for j in moving:  # the root always; other joints only where an expression moves them
        anim.channel(base + int(j), "translation", times, motion.offset_tj3[:, j], g.VEC3)
    key_t, scale = _visibility_keys(motion.times_t, t0, t_end, motion.fps)
    if T and (scale == 0).any():
        anim.channel(base, "scale", key_t, np.repeat(scale[:, None], 3, 1), g.VEC3, g.ANIM_STEP)
        if scale[0] == 0:
            gltf.nodes[base].scale = [0.0, 0.0, 0.0]
    # bind pose: every joint unrotated at its rest position (the first frame's shape)
    ibm = np.tile(np.eye(4), (len(motion.names), 1, 1))
    ibm[:, :3, 3] = -motion.rest_j3
    skin = g.Skin(name=f"person{pid}", joints=list(range(base, base + len(motion.names))), skeleton=base,
                  inverseBindMatrices=blob.add(ibm.transpose(0, 2, 1).astype(np.float32), g.MAT4))
    gltf.skins.append(skin)
    mesh = _body_mesh(gltf, blob, model, np.asarray(result.betas, np.float64), f"person{pid}",
                      _material(gltf, f"person{pid}", colour))
    gltf.nodes.append(g.Node(name=f"person{pid}/body", mesh=mesh, skin=len(gltf.skins) - 1))
    gltf.scenes[0].nodes.append(len(gltf.nodes) - 1)


def _frustum_mesh(gltf: g.GLTF2, blob: _Blob, name: str, tan_x: float, tan_y: float, material: int) -> int:
    """Lines of a small view pyramid in glTF camera axes (looking down -z), a tick on its top edge."""
    d = FRUSTUM_DEPTH_M
    x, y = d * tan_x, d * tan_y
    v = np.array([[0, 0, 0], [-x, -y, -d], [x, -y, -d], [x, y, -d], [-x, y, -d], [0, 1.3 * y, -d]], np.float32)
    lines = np.array([0, 1, 0, 2, 0, 3, 0, 4, 1, 2, 2, 3, 3, 4, 4, 1, 3, 5, 5, 4], np.uint32)
    prim = g.Primitive(attributes=g.Attributes(POSITION=blob.add(v, g.VEC3, g.ARRAY_BUFFER, bounds=True)),
                       indices=blob.add(lines, g.SCALAR, g.ELEMENT_ARRAY_BUFFER), material=material, mode=g.LINES)
    gltf.meshes.append(g.Mesh(name=name, primitives=[prim]))
    return len(gltf.meshes) - 1


def _add_cameras(gltf: g.GLTF2, blob: _Blob, world: int, rig) -> None:
    flip = np.diag([1.0, -1.0, -1.0])  # glTF camera axes (x right, y up, looking down -z) in OpenCV's
    material = _material(gltf, "cameras", (0.15, 0.2, 0.3), 1.0)
    for cam in rig:
        fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
        gltf.cameras.append(g.Camera(name=cam.name, type=g.PERSPECTIVE, perspective=g.Perspective(
            yfov=float(2 * np.arctan(cam.height / (2 * fy))), aspectRatio=cam.width / cam.height, znear=0.05)))
        R_wc = cam.R.T
        shape = _frustum_mesh(gltf, blob, f"camera/{cam.name}", cam.width / (2 * fx), cam.height / (2 * fy), material)
        gltf.nodes.append(g.Node(name=f"camera/{cam.name}/frustum", mesh=shape))
        gltf.nodes.append(g.Node(name=f"camera/{cam.name}", camera=len(gltf.cameras) - 1, children=[len(gltf.nodes) - 1],
                                 translation=(-R_wc @ cam.t).tolist(), rotation=_quat(R_wc @ flip)))
        gltf.nodes[world].children.append(len(gltf.nodes) - 1)


def _add_floor(gltf: g.GLTF2, blob: _Blob, world: int, xy_lo: np.ndarray, xy_hi: np.ndarray) -> None:
    (x0, y0), (x1, y1) = xy_lo - FLOOR_MARGIN_M, xy_hi + FLOOR_MARGIN_M
    v = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], np.float32)
    n = np.tile(np.array([0, 0, 1], np.float32), (4, 1))
    prim = g.Primitive(attributes=g.Attributes(POSITION=blob.add(v, g.VEC3, g.ARRAY_BUFFER, bounds=True),
                                               NORMAL=blob.add(n, g.VEC3, g.ARRAY_BUFFER)),
                       indices=blob.add(np.array([0, 1, 2, 0, 2, 3], np.uint32), g.SCALAR, g.ELEMENT_ARRAY_BUFFER),
                       material=_material(gltf, "floor", (0.6, 0.6, 0.6), 1.0))
    gltf.meshes.append(g.Mesh(name="floor", primitives=[prim]))
    gltf.nodes.append(g.Node(name="floor", mesh=len(gltf.meshes) - 1))
    gltf.nodes[world].children.append(len(gltf.nodes) - 1)


def write_gltf(path: str | Path, people: list[tuple[int, object]], model, rig=None, floor: bool = True,
               colours: dict | None = None, generator: str = "mamma-kit") -> dict:
    """Write ``people`` ([(person id, SmplxResult)], all fitted with ``model``) to ``path``
    (.glb binary, else .gltf with the buffer inside). Returns a summary."""
    from mamma_kit.core.io import atomic_path

    path = Path(path)
    gltf = g.GLTF2(scene=0, scenes=[g.Scene(name="capture", nodes=[0])],
                   nodes=[g.Node(name="world", rotation=_quat(Z_UP_TO_Y_UP))])
    blob = _Blob(gltf)
    anim = _Animation(blob)
    motions = [make_motion(model, r) for _, r in people]
    t0 = min(float(m.times_t[0]) for m in motions)
    t_end = max(float(m.times_t[-1]) for m in motions)
    for (pid, r), motion in zip(people, motions):
        colour = (colours or {}).get(pid, (0.7, 0.7, 0.7))
        _add_person(gltf, blob, anim, 0, pid, model, r, motion, t0, t_end, colour)
    if rig is not None:
        _add_cameras(gltf, blob, 0, rig)
    if floor:
        xy = np.concatenate([r.joints[:, 0, :2] for _, r in people])
        _add_floor(gltf, blob, 0, xy.min(0), xy.max(0))
    gltf.animations.append(anim.anim)
    gltf.buffers.append(g.Buffer(byteLength=blob.size))
    gltf.set_binary_blob(blob.bytes())
    with atomic_path(path) as tmp:
        if path.suffix.lower() != ".glb":
            gltf.convert_buffers(g.BufferFormat.DATAURI)
        gltf.save(str(tmp), asset=g.Asset(generator=generator, version="2.0"))
    return {"path": str(path), "persons": [pid for pid, _ in people], "frames": {pid: r.num_frames for pid, r in people},
            "cameras": len(rig) if rig is not None else 0, "seconds": t_end - t0, "bytes": path.stat().st_size}
