"""Crop datasets for training MammaNet: `mamma-kit synth RECIPE --crops N --out DIR`.

Each sample scene draws 1-3 people (shapes, looks, a motion and a random instant of it,
plus random extra joint perturbations and finger poses), a random environment, and 1-4
random cameras around them (distance, height, focal length, roll, lens distortion). For
every visible person a *crop camera* — the camera with K cropped and scaled to a context
box (1.6 x the person's box, 3:4 W:H) — renders directly at the crop resolution, so
nothing outside the crop is ever ray cast. Labels: landmark pixels, visibility (ray cast),
person contact (signed distance to the other bodies' proxies < 1 cm) and floor contact.

Shards: DIR/shard_0000.npz, shard_0001.npz, ... with images (N, H, W, 3) uint8, instance
(N, H, W) uint8 (0 background, 1 the target, 2.. others), xy (N, L, 2) float32 crop pixels, visibility,
contact, floor_contact (N, L) uint8, box (N, 4) float32 (target's tight box in crop px);
and DIR/meta.json.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from mamma_kit.body.rest_pose import arm_rest_rotations
from mamma_kit.core import log
from mamma_kit.core.camera import Camera
from mamma_kit.core.io import write_json, write_npz
from mamma_kit.synth.appearance import person_colors
from mamma_kit.synth.motion import (MotionClip, euler_to_params, generate_motion,
                                    LIMITS, N_JOINTS, L_HAND, R_HAND)
from mamma_kit.synth.render import CameraRenderer, Environment, PersonMesh, PeopleScene
from mamma_kit.synth.rig import look_at_rotation

CROP_HW = (320, 240)
CONTEXT = 1.6
SINGLE_KINDS = ("walk", "turn", "squat", "jump", "gestures", "floor", "stand", "mixed")
COUPLE_KINDS = ("couple-dance", "hug", "handshake", "push")


def crop_camera(cam: Camera, box_xyxy: np.ndarray, out_hw=CROP_HW, context: float = CONTEXT) -> Camera:
    """The camera whose image is the 3:4 context crop around ``box`` resized to ``out_hw``."""
    x1, y1, x2, y2 = box_xyxy
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
    w, h = (x2 - x1) * context, (y2 - y1) * context
    H, W = out_hw
    aspect = W / H
    if w / h > aspect:
        h = w / aspect
    else:
        w = h * aspect
    s = W / w  # px of crop per px of image
    # crop pixel u = s * (x - (cx - w/2)) + 0.5 * s - 0.5 (pixel-centre convention)
    A = np.array([[s, 0, -s * (cx - w / 2) + 0.5 * s - 0.5], [0, s, -s * (cy - h / 2) + 0.5 * s - 0.5], [0, 0, 1]])
    return cam.copy(K=A @ cam.K, size=(W, H))


def _random_camera(rng: np.random.Generator, target: np.ndarray, name: str) -> Camera:
    """A phone-like camera 2.5-8 m away at 0.4-3.2 m height, looking near the target
    (sometimes held in portrait)."""
    az = rng.uniform(0, 2 * np.pi)
    dist = rng.uniform(2.5, 8.0)
    C = np.array([target[0] + dist * np.cos(az), target[1] + dist * np.sin(az), rng.uniform(0.4, 3.2)])
    look = target + rng.normal(0, 0.25, 3) * [1, 1, 0.5]
    R = look_at_rotation(C, look, roll_deg=rng.normal(0, 4) + (90 if rng.random() < 0.15 else 0))
    w, h = 1920, 1080
    f = rng.uniform(0.7, 1.6) * w
    K = np.array([[f, 0, w / 2 + rng.normal(0, 10)], [0, f, h / 2 + rng.normal(0, 10)], [0, 0, 1]])
    # pinhole: a crop spans a small part of a phone's field where lens distortion is mild,
    # and undistorting every crop's rays would triple the rendering time
    return Camera(name, (w, h), K, np.zeros(5), "radtan", R, -R @ C)


def _perturb(clip_params: dict, rng: np.random.Generator, amount: float) -> None:
    """Random extra joint rotations and finger poses for pose variety (in place, (P, D))."""
    P = clip_params["body_pose"].shape[0]
    clip_params["body_pose"] = clip_params["body_pose"] + rng.normal(0, amount, (P, 63))
    for key in ("left_hand_pose", "right_hand_pose"):
        sign = -1 if key.startswith("left") else 1
        curl = rng.uniform(-0.1, 1.3, (P, 5))
        hp = clip_params[key].reshape(P, 15, 3)
        for f in range(4):
            for k in range(3):
                hp[:, 3 * f + k, 2] = sign * curl[:, f] * (1.0 + 0.2 * k) + rng.normal(0, 0.08, P)
        hp[:, 12:, :] += rng.normal(0, 0.25, (P, 3, 3))
        clip_params[key] = hp.reshape(P, 45)


def write_crop_shards(recipe_ref, out: str | Path, n: int, seed: int | None = None, shard_size: int = 500,
                      workers: int | None = None) -> dict:
    """Render ``n`` person crops into shards under ``out`` (recipe gives defaults only; the
    scenes are randomised far beyond one recipe). Each shard is a unit of work with its own
    random stream (from the seed and the shard's index), so the shards are the same whatever
    executor or worker count renders them."""
    from functools import partial

    from mamma_kit.body.model import load_body_model
    from mamma_kit.body.skeleton import LANDMARK_PART_NAMES
    from mamma_kit.core.executor import run_units
    from mamma_kit.synth.recipe import load_recipe

    recipe = load_recipe(recipe_ref, seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    units = [(i, min(shard_size, n - start)) for i, start in enumerate(range(0, n, shard_size))]
    done = run_units(partial(render_shard, out=out, seed=recipe.seed), units, workers)
    kinds_used: dict[str, int] = {}
    for part in done:
        for k, v in part["scene_kinds"].items():
            kinds_used[k] = kinds_used.get(k, 0) + v
    body = load_body_model("open")
    meta = {"landmark_set": f"{body.name}:{body.landmarks.source}", "body_model": body.name,
            "landmark_parts": body.landmark_parts.tolist(), "landmark_part_names": list(LANDMARK_PART_NAMES),
            "body_sha256": body.sha256, "recipe": recipe.name, "seed": recipe.seed,
            "count": sum(part["count"] for part in done), "crop_hw": list(CROP_HW), "context": CONTEXT,
            "shards": [part["shard"] for part in done], "scene_kinds": kinds_used,
            "seconds": round(time.perf_counter() - t0, 1)}
    write_json(out / "meta.json", meta)
    return meta


def render_shard(unit: tuple[int, int], out: Path, seed: int) -> dict:
    """One shard (index, crops) of write_crop_shards: out/shard_<index>.npz (here or in a worker)."""
    import torch

    index, n = unit
    # one torch thread, as in a pool worker: the contact solver's sums then add up in the same order
    # wherever the shard renders, so a shard is the same on every executor
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _render_shard(index, n, out, seed)
    finally:
        torch.set_num_threads(threads)


def _render_shard(index: int, n: int, out: Path, seed: int) -> dict:
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.body.model import load_body_model
    from mamma_kit.body.skeleton import PART_NAMES
    from mamma_kit.synth.interact import fit_floor_and_contacts
    from mamma_kit.synth.scene import CONTACT_DIST, FLOOR_DIST, person_contact, sample_betas
    from mamma_kit.synth.render import vertex_normals

    rng = np.random.default_rng([seed, 7919, index])
    body = load_body_model("open")
    faces = body.np.faces
    lm = body.landmark_ids
    part_names = [PART_NAMES[i] for i in body.vertex_part]
    arm_rest = arm_rest_rotations(body.np.J_template)
    H, W = CROP_HW
    buf: dict[str, list] = {k: [] for k in ("images", "instance", "xy", "visibility", "contact", "floor_contact", "box")}
    made = 0
    kinds_used: dict[str, int] = {}
    envs: list[Environment] = []
    progress = log.progress_bar()
    with progress:
        task = progress.add_task(f"crops, shard {index}", total=n)
        while made < n:
            couple = rng.random() < 0.4
            kind = str(rng.choice(COUPLE_KINDS if couple else SINGLE_KINDS))
            P = 2 if couple else int(rng.choice([1, 1, 2, 3]))
            kinds_used[kind] = kinds_used.get(kind, 0) + 1
            # a few instants of a 3 s motion: one is rendered, the rest keep the contact
            # solver's smoothness term meaningful at a fraction of the cost of a dense clip
            tracks, t, contacts = generate_motion(kind, P, 3.0, rng, area=rng.uniform(1.5, 4.0), rate=2.0,
                                                  t0=0.0, t1=3.0)
            betas = sample_betas(rng, P, spread=1.0)
            per = [euler_to_params(tr, arm_rest) for tr in tracks]
            params = {k: np.stack([p[k] for p in per]) for k in per[0]}
            clip = MotionClip(t, betas, params, kind, contacts)
            fit_floor_and_contacts(body, clip, [tr.ground for tr in tracks], iters=25)
            s = float(rng.choice(t[1:-1]))
            prm = clip.at(s)
            if not couple:
                _perturb(prm, rng, 0.12)
            prm["betas"] = betas
            verts, _ = pose_mesh_np(body, prm)  # (P, V, 3)
            if not couple:  # perturbation moved feet: put the lowest point back on the floor
                verts[..., 2] -= verts[..., 2].min(1, keepdims=True)
            colors = [person_colors(pose_mesh_np(body, {"betas": betas[p]})[0], part_names, rng) for p in range(P)]
            people = [PersonMesh(verts[p], faces, colors[p]) for p in range(P)]
            scene = PeopleScene(people)
            if len(envs) < 12:  # textures are costly to make: keep a pool of environments
                envs.append(Environment(rng))
            env = envs[int(rng.integers(len(envs)))]
            contact = person_contact(body, verts[:, None], CONTACT_DIST)[:, 0] if P > 1 else np.zeros((P, len(lm)))
            floor = np.stack([(verts[p, lm, 2] < FLOOR_DIST) & (vertex_normals(verts[p], faces)[lm, 2] < -0.3)
                              for p in range(P)]).astype(np.uint8)
            centre = verts.reshape(-1, 3).mean(0)
            for ci in range(int(rng.integers(2, 6))):
                cam = _random_camera(rng, centre, f"c{ci}")
                for p in range(P):
                    uv = cam.project(verts[p])
                    if not np.isfinite(uv).all():
                        continue
                    box = np.r_[uv.min(0), uv.max(0)]
                    bh = box[3] - box[1]
                    if bh < 60 or bh > 2.5 * cam.size[1]:
                        continue
                    # sometimes crop off-centre so parts of the person leave the crop (truncation)
                    if rng.random() < 0.2:
                        shift = rng.uniform(-0.35, 0.35, 2) * [box[2] - box[0], bh]
                        box = box + np.r_[shift, shift]
                    cc = crop_camera(cam, box)
                    fr, vis = CameraRenderer(cc, env).render(people, rng, rng.uniform(0, 4),
                                                             [verts[q, lm] for q in range(P)], scene)
                    inst = np.zeros((H, W), np.uint8)
                    others = 2
                    for q in range(P):
                        if q == p:
                            inst[fr.instance == q] = 1
                        elif (fr.instance == q).any():
                            inst[fr.instance == q] = others
                            others += 1
                    if (inst == 1).sum() < 200:
                        continue
                    ys, xs = np.nonzero(inst == 1)
                    buf["images"].append(fr.rgb)
                    buf["instance"].append(inst)
                    buf["xy"].append(cc.project(verts[p, lm]).astype(np.float32))
                    buf["visibility"].append(vis[p].astype(np.uint8))
                    buf["contact"].append(contact[p].astype(np.uint8))
                    buf["floor_contact"].append(floor[p])
                    buf["box"].append(np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], np.float32))
                    made += 1
                    progress.advance(task)
                    if made >= n:
                        break
                if made >= n:
                    break
    return {"shard": _flush(out, index, buf), "count": made, "scene_kinds": kinds_used}


def _flush(out: Path, index: int, buf: dict) -> str:
    name = f"shard_{index:04d}.npz"
    write_npz(out / name, **{k: np.stack(v) for k, v in buf.items()})
    for v in buf.values():
        v.clear()
    return name
