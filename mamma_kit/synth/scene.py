"""A synthetic scene: bodies with motion and looks, rendered into each camera's video with
per-frame ground truth (masks, 2D landmarks, visibility, contact labels)."""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mamma_kit.body.rest_pose import arm_rest_rotations
from mamma_kit.core import log
from mamma_kit.core.manifest import producer
from mamma_kit.core.timecode import frames_to_timecode
from mamma_kit.core.tracks import LandmarkTracks, MaskTracks
from mamma_kit.synth.appearance import person_colors
from mamma_kit.synth.motion import MotionClip, euler_to_params, generate_motion
from mamma_kit.synth.recipe import Recipe
from mamma_kit.synth.render import CameraRenderer, Environment, PersonMesh, flash_rows
from mamma_kit.synth.rig import SynthCamera
from mamma_kit.video.writer import VideoWriter

MOTION_RATE = 60.0  # Hz of the dense motion samples (interpolated to every frame time)
CONTACT_DIST = 0.01  # m: a landmark within 1 cm of (or inside) the other body is in contact
FLOOR_DIST = 0.015  # m above the floor, with a downward-facing normal: floor contact


def sample_betas(rng: np.random.Generator, n: int, spread: float = 0.9) -> np.ndarray:
    return np.clip(rng.normal(0, spread, (n, 16)), -2.5, 2.5) * np.r_[np.ones(6), np.full(10, 0.5)]


def camera_rng(seed: int, camera: str) -> np.random.Generator:
    """The random stream of one camera's rendering (its sensor noise), the same in every process:
    zlib.crc32 of the name, not hash(), which Python salts per process (PYTHONHASHSEED) and which made
    one recipe and seed render other noise, and so other figures, on every run."""
    return np.random.default_rng([seed, zlib.crc32(camera.encode())])


@dataclass
class Scene:
    recipe: Recipe
    body: object  # BodyModel
    clip: MotionClip
    colors: list[np.ndarray]  # per person (V, 3)
    env: Environment

    @property
    def n_people(self) -> int:
        return self.clip.n_people

    def pose(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full meshes and joints of every person at scene times s (T,):
        verts (P, T, V, 3), joints (P, T, 55, 3)."""
        from mamma_kit.body.lbs import pose_mesh_np

        prm = self.clip.at(np.asarray(s, float))  # each (P, T, D)
        prm["betas"] = np.repeat(self.clip.betas[:, None], len(np.atleast_1d(s)), 1)
        P, T = self.n_people, len(np.atleast_1d(s))
        if P == 0:  # a scene without people (board-only sessions)
            return (np.zeros((0, T, len(self.body.np.v_template), 3)), np.zeros((0, T, 55, 3)))
        flat = {k: v.reshape(P * T, -1) for k, v in prm.items()}
        verts, joints = pose_mesh_np(self.body, flat)
        return verts.reshape(P, T, -1, 3), joints.reshape(P, T, -1, 3)

    # ---- per-camera rendering ------------------------------------------------------------
    def render_camera(self, sc: SynthCamera, path: Path, audio, recipe: Recipe, gt: Path) -> None:
        cam = sc.camera
        rng = camera_rng(recipe.seed, cam.name)
        renderer = CameraRenderer(cam, self.env)
        s_all = sc.scene_times
        T, P = len(s_all), self.n_people
        faces = self.body.np.faces
        lm_ids = self.body.landmark_ids
        w, h = cam.size
        timecode = None
        if recipe.tmcd:
            base = recipe.ltc.get("start", "01:00:00:00") if recipe.ltc else "01:00:00:00"
            timecode = _start_timecode(base, recipe.fps, float(s_all[0]))
        sr = int(recipe.audio["sample_rate"]) if audio is not None else None
        codec = "pcm_s16le" if recipe.audio.get("codec") == "pcm" else "aac"
        n_ch = audio[0].shape[1] if audio is not None else 1
        lt = LandmarkTracks.empty(cam.name, (w, h), sc.frame_times, np.arange(P), len(lm_ids),
                                  landmark_set=f"{self.body.name}:{self.body.landmarks.source}", source="gt")
        masks: dict[tuple[int, int], np.ndarray] = {}
        noise = float(recipe.render.get("noise", 2.0))
        flash = recipe.flash
        if flash is not None:
            on_s = np.asarray(flash["t"], float)
            dur = float(flash.get("duration_s", 0.0))
            off_s = on_s + dur if dur > 0 else np.full(len(on_s), np.inf)
        chunk = 16
        with VideoWriter(path, w, h, fps=recipe.fps, crf=int(recipe.render.get("crf", 20)), audio_rate=sr,
                         audio_channels=n_ch, audio_codec=codec, timecode=timecode,
                         **recipe.writer_options(cam.name)) as wr:
            for c0 in log.track(range(0, T, chunk), f"render {cam.name}"):
                idx = np.arange(c0, min(c0 + chunk, T))
                verts, _ = self.pose(s_all[idx])  # (P, n, V, 3)
                contact, floor = self.contact_labels(verts, s_all[idx])  # (P, n, L)
                for j, k in enumerate(idx):
                    people = [PersonMesh(verts[p, j], faces, self.colors[p]) for p in range(P)]
                    lms = [verts[p, j, lm_ids] for p in range(P)]
                    light = None if flash is None else flash_rows(
                        sc.clock, float(sc.frame_times[k]), h, sc.exposure_s, sc.readout_s, on_s, off_s,
                        float(flash.get("gain", 0.8)))
                    fr, vis = renderer.render(people, rng, noise, lms, light_h=light)
                    wr.write_frame(fr.rgb, float(sc.frame_times[k]))
                    for p in range(P):
                        m = fr.instance == p
                        if m.any():
                            masks[(int(k), p)] = m
                        xy = cam.project(lms[p])
                        inside = np.isfinite(xy).all(1) & (xy[:, 0] > -0.5) & (xy[:, 0] < w - 0.5) & \
                            (xy[:, 1] > -0.5) & (xy[:, 1] < h - 0.5)
                        lt.valid[k, p] = bool(inside.any() and m.any())
                        lt.xy[k, p] = xy
                        lt.sigma[k, p] = 0.0
                        lt.visibility[k, p] = vis[p]
                        lt.contact[k, p] = contact[p, j]
                        lt.floor_contact[k, p] = floor[p, j]
            if audio is not None:
                wr.write_audio(audio[0], start_s=audio[1])
        prod = producer("mamma-kit synth (ground truth)")
        lt.producer = prod
        lt.save(gt / "landmarks" / f"{cam.name}.npz")
        MaskTracks.from_masks(cam.name, (w, h), sc.frame_times, np.arange(P), masks,
                              producer=prod).save(gt / "masks" / f"{cam.name}.npz")

    def contact_labels(self, verts: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per landmark: person contact (within 1 cm of, or inside, another body) and floor
        contact (within 1.5 cm of the floor with a downward normal). verts (P, n, V, 3) at scene
        times s (n,) -> two (P, n, L) float32 arrays.

        Person contact (an exact signed distance: the costly part) is labelled once per sample
        of the dense motion grid (MOTION_RATE) and every camera takes the nearest sample's
        labels (within 8 ms; cameras' VFR times never coincide, so per-frame labels would be
        recomputed for every camera). Floor contact is exact per frame."""
        from mamma_kit.synth.render import vertex_normals

        P, n = verts.shape[:2]
        lm = self.body.landmark_ids
        faces = self.body.np.faces
        L = len(lm)
        contact = np.zeros((P, n, L), np.float32)
        floor = np.zeros((P, n, L), np.float32)
        for p in range(P):
            for j in range(n):
                nz = vertex_normals(verts[p, j], faces)[lm, 2]
                floor[p, j] = (verts[p, j, lm, 2] < FLOOR_DIST) & (nz < -0.3)
        if P > 1:
            g = self._grid_index(s)
            cache = self.__dict__.setdefault("_contact_cache", {})
            todo = sorted(set(g.tolist()) - set(cache))
            if todo:
                cache.update(zip(todo, _contact_unit((self, todo))))
            contact[:] = np.stack([cache[gi] for gi in g], 1)
        return contact, floor

    def _grid_index(self, s: np.ndarray) -> np.ndarray:
        grid = self.clip.times
        return np.clip(np.round(np.interp(np.asarray(s, float), grid, np.arange(len(grid)))).astype(int), 0,
                       len(grid) - 1)

    def label_contacts(self, times: list[np.ndarray], workers: int | None = None) -> None:
        """Person-contact labels of every motion sample any of ``times`` needs, computed once
        (split over worker processes) before the cameras are rendered, each in its own process."""
        from mamma_kit.core.executor import default_workers, run_units

        if self.n_people < 2:
            return
        need = sorted(set(np.concatenate([self._grid_index(t) for t in times]).tolist()))
        n = default_workers(len(need), workers)
        parts = [need[i::n] for i in range(n)]
        cache = self.__dict__.setdefault("_contact_cache", {})
        for part, labels in zip(parts, run_units(_contact_unit, [(self, p) for p in parts], n)):
            cache.update(zip(part, labels))

    # ---- ground-truth bodies ------------------------------------------------------------
    def write_gt_bodies(self, gt: Path, ref: SynthCamera) -> None:
        """SMPL-X parameters + joints of every person at the reference camera's frames
        (frame_times in scene time; that camera's own timestamps are in its landmark file)."""
        from mamma_kit.core.smplxfile import SmplxResult, write_smplx_result

        s = ref.scene_times
        prm = self.clip.at(s)
        _, joints = self.pose(s)
        for p in range(self.n_people):
            r = SmplxResult.from_params({k: v[p] for k, v in prm.items()} | {"betas": self.clip.betas[p]},
                                        joints[p], s, self.recipe.fps, self.body.name, self.body.sha256,
                                        producer=producer("mamma-kit synth (ground truth)")
                                        | {"reference_camera": ref.camera.name})
            write_smplx_result(gt / "smplx" / f"person_{p}.npz", r)


def _contact_unit(unit) -> list[np.ndarray]:
    """Person-contact labels (P, L) at the given motion-grid samples of a scene."""
    scene, idx = unit
    v_grid, _ = scene.pose(scene.clip.times[idx])
    lab = person_contact(scene.body, v_grid, CONTACT_DIST)  # (P, len(idx), L)
    return [lab[:, k] for k in range(len(idx))]


def person_contact(body, verts: np.ndarray, dist: float) -> np.ndarray:
    """(P, n, L) 1 where a landmark of person p lies within ``dist`` of (or inside) any other
    person's body, by the signed distance to the other's closed proxy mesh; only landmarks
    near the other's bounding box are tested."""
    from mamma_kit.body.proxy import signed_distance

    P, n = verts.shape[:2]
    lm = body.landmark_ids
    proxy = body.proxy
    out = np.zeros((P, n, len(lm)), np.float32)
    for a in range(P):
        for b in range(P):
            if a == b:
                continue
            pts = verts[a][:, lm]  # (n, L, 3)
            other = verts[b][:, proxy.vertex_ids]  # (n, Vp, 3)
            # only landmarks within 5 cm of a proxy vertex can be within 1 cm of its surface
            # (proxy edges are ~3 cm), so the exact signed distance runs on few points
            near_d = torch.cdist(torch.from_numpy(pts).float(), torch.from_numpy(other).float()).min(-1).values
            near = (near_d < 0.05).numpy()  # (n, L)
            for j in np.flatnonzero(near.any(1)):
                ids = np.flatnonzero(near[j])
                with torch.no_grad():
                    sd = signed_distance(torch.from_numpy(pts[j, ids]).float(),
                                         torch.from_numpy(other[j]).float(), proxy.faces,
                                         neighbours=proxy.neighbours)
                out[a, j, ids] = np.maximum(out[a, j, ids], (sd.numpy() < dist).astype(np.float32))
    return out


def _start_timecode(base: str, fps: float, s_first: float) -> str:
    """tmcd start timecode (whole frames) of a camera whose first frame was exposed at
    scene time ``s_first``, when scene time 0 carries the label ``base``."""
    from mamma_kit.core.timecode import rate_fraction, timecode_to_frames

    n = timecode_to_frames(base, fps) + int(round(s_first * float(rate_fraction(fps))))
    return str(frames_to_timecode(n, fps))


def build_scene(recipe: Recipe, cams: list[SynthCamera]) -> Scene:
    from mamma_kit.body.model import load_body_model
    from mamma_kit.synth.interact import fit_floor_and_contacts

    body = load_body_model("open")
    rng = np.random.default_rng(recipe.seed + 3)
    s0 = min(float(c.scene_times[0]) for c in cams) - 0.1
    s1 = max(float(c.scene_times[-1]) for c in cams) + 0.1
    P = recipe.people_count
    room = recipe.scene.get("room_radius_m")
    tracks, t, contacts = generate_motion(recipe.motion_kind, P, recipe.duration_s, rng,
                                          area=float(recipe.motion.get("area_m", 3.0)), rate=MOTION_RATE,
                                          t0=s0, t1=s1, exit_routes=exit_routes(room, recipe.scene.get("doors_deg", [])),
                                          leave=int(recipe.motion.get("leave", 0)))
    betas = sample_betas(rng, P)
    for i, override in enumerate(recipe.people[:P]):
        if "betas" in override:
            b = np.zeros(16)
            vals = np.asarray(override["betas"], float)[:16]
            b[:len(vals)] = vals
            betas[i] = b
    arm_rest = arm_rest_rotations(body.np.J_template)
    per = [euler_to_params(tr, arm_rest) for tr in tracks]
    params = {k: np.stack([p[k] for p in per]) for k in per[0]} if per else {}
    clip = MotionClip(t, betas, params, recipe.motion_kind, contacts)
    if P:
        fit_floor_and_contacts(body, clip, [tr.ground for tr in tracks])
    from mamma_kit.body.skeleton import PART_NAMES

    part_names = [PART_NAMES[i] for i in body.vertex_part]
    colors = []
    from mamma_kit.body.lbs import pose_mesh_np

    for p in range(P):
        rest, _ = pose_mesh_np(body, {"betas": betas[p]})
        override = recipe.people[p] if p < len(recipe.people) else {}
        colors.append(person_colors(rest, part_names, rng, override.get("look")))
    props = []
    if recipe.scene.get("chairs") or recipe.scene.get("tables"):
        from mamma_kit.synth.props import place_props

        paths = np.stack([tr.xy for tr in tracks]) if tracks else np.zeros((0, 1, 2))
        props = place_props(recipe.scene["chairs"], recipe.scene.get("tables", 0), np.random.default_rng(recipe.seed + 13),
                            paths, np.array([c.camera.center[:2] for c in cams]), room or 8.0)
    env = Environment(np.random.default_rng(recipe.seed + 5), room_radius=room,
                      doors_deg=tuple(recipe.scene.get("doors_deg", [])), props=props)
    return Scene(recipe, body, clip, colors, env)


def exit_routes(room_radius: float | None, doors_deg: list[float]) -> list[np.ndarray]:
    """Per door, the way out of a round room (R, 2): to just inside the doorway, through it, then
    sideways behind the wall, where no camera inside sees."""
    out = []
    for a in np.radians(doors_deg) if room_radius else []:
        u, side = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
        out.append(np.stack([(room_radius - 0.8) * u, (room_radius + 0.7) * u,
                             (room_radius + 0.9) * u + 1.8 * side]))
    return out
