"""Ray-cast rendering of people in an outdoor-like scene, through the real lens model.

Per camera, the world ray of every pixel centre is computed once (distortion included);
per frame, only pixels inside the people's projected bounding boxes are ray cast against
their meshes with embree (trimesh + embreex); the floor (z = 0, textured) and the
background (a textured cylinder of buildings/trees and a sky) are intersected
analytically. Outputs: RGB, per-person instance ids, depth, and landmark visibility.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.core.camera import Camera

BACKGROUND_RADIUS = 14.0
BACKGROUND_HEIGHT = 7.0
ROOM_WALL_HEIGHT = 2.8  # m, the wall of a room scene
DOOR_WIDTH, DOOR_HEIGHT = 1.0, 2.1  # m, its doorways


@dataclass
class PersonMesh:
    """A coloured triangle mesh: a person, or a piece of furniture (synth/props.py)."""

    verts: np.ndarray  # (V, 3) world
    faces: np.ndarray  # (F, 3)
    colors: np.ndarray  # (V, 3) float in [0, 1]


@dataclass
class Frame:
    rgb: np.ndarray  # (H, W, 3) uint8
    instance: np.ndarray  # (H, W) int16, person index or -1
    depth: np.ndarray  # (H, W) float32 z-depth (camera frame), inf for sky


class Environment:
    """Floor, background, light and furniture of a scene (deterministic in its seed).

    By default the background is a distant backdrop (buildings and trees on a cylinder of
    BACKGROUND_RADIUS m, the floor reaching past it); ``room_radius`` makes it a room: a wall of
    ROOM_WALL_HEIGHT m at that radius that hides whatever is behind it, with dark doorways at the
    azimuths ``doors_deg``, through which one sees out. ``props``: static meshes (furniture)."""

    def __init__(self, rng: np.random.Generator, room_radius: float | None = None,
                 doors_deg: tuple[float, ...] = (), props: list["PersonMesh"] | None = None):
        self.rng = rng
        self.floor_tex = _floor_texture(rng)  # covers 24 x 24 m
        self.wall_tex = _wall_texture(rng)
        sun_az, sun_el = rng.uniform(0, 2 * np.pi), rng.uniform(np.radians(35), np.radians(70))
        self.sun = np.array([np.cos(sun_el) * np.cos(sun_az), np.cos(sun_el) * np.sin(sun_az), np.sin(sun_el)])
        self.ambient = rng.uniform(0.35, 0.5)
        self.sky_top = np.array([0.35, 0.55, 0.85]) * rng.uniform(0.9, 1.1)
        self.sky_bottom = np.array([0.8, 0.85, 0.9])
        self.room = room_radius is not None
        self.radius = float(room_radius) if self.room else BACKGROUND_RADIUS
        self.wall_height = ROOM_WALL_HEIGHT if self.room else BACKGROUND_HEIGHT
        self.doors = np.radians(np.asarray(doors_deg, float))
        self.props = list(props or [])

    def shade_floor(self, X_n3: np.ndarray, blobs_xy: np.ndarray) -> np.ndarray:
        tex = _lookup(self.floor_tex, X_n3[:, 0] / 24.0 + 0.5, X_n3[:, 1] / 24.0 + 0.5)
        light = self.ambient + (1 - self.ambient) * max(self.sun[2], 0)
        c = tex * light
        if len(blobs_xy):  # soft contact shadow under each person
            d2 = ((X_n3[:, None, :2] - blobs_xy[None]) ** 2).sum(-1)
            c = c * (1 - 0.45 * np.exp(-d2 / 0.12).max(1))[:, None]
        return c

    def shade_background(self, C: np.ndarray, d_n3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays that miss people and floor: the wall (or backdrop) or the sky. Returns the colours
        (N, 3) and the distance along each ray to a surface that hides what is behind it (N,):
        the room's wall, inf for the sky, doorways and the outdoor backdrop."""
        out = np.empty((len(d_n3), 3))
        a = (d_n3[:, :2] ** 2).sum(1)
        b = 2 * (d_n3[:, :2] * C[:2]).sum(1)
        c = (C[:2] ** 2).sum() - self.radius ** 2
        disc = np.maximum(b * b - 4 * a * c, 0)
        t = (-b + np.sqrt(disc)) / np.maximum(2 * a, 1e-12)
        z = C[2] + t * d_n3[:, 2]
        wall = (z < self.wall_height) & (a > 1e-9)
        P = C + t[:, None] * d_n3
        az = np.arctan2(P[:, 1], P[:, 0])
        ang = az / (2 * np.pi) + 0.5
        tex = _lookup(self.wall_tex, ang, np.clip(z / self.wall_height, 0, 1))
        out[wall] = tex[wall] * (self.ambient + 0.45)
        h = np.clip(d_n3[~wall, 2], 0, 1)[:, None]
        out[~wall] = self.sky_bottom * (1 - h) + self.sky_top * h
        hides = np.full(len(d_n3), np.inf)
        if self.room:
            door = np.zeros(len(d_n3), bool)
            for a0 in self.doors:  # a doorway DOOR_WIDTH wide and DOOR_HEIGHT tall: dark, open
                gap = np.abs((az - a0 + np.pi) % (2 * np.pi) - np.pi) * self.radius
                door |= wall & (gap < DOOR_WIDTH / 2) & (z < DOOR_HEIGHT)
            out[door] = np.array([0.16, 0.14, 0.12]) * (0.9 + 0.2 * np.clip(z[door] / DOOR_HEIGHT, 0, 1))[:, None]
            hides = np.where(wall & ~door, t, np.inf)
        return out, hides


def _lookup(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup in a tiling texture (H, W, 3) at u, v in [0, 1)."""
    H, W = tex.shape[:2]
    x = (u % 1.0) * W - 0.5
    y = (v % 1.0) * H - 0.5
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    x0 %= W
    y0 %= H
    x1 = (x0 + 1) % W
    y1 = (y0 + 1) % H
    return (tex[y0, x0] * (1 - fx) * (1 - fy) + tex[y0, x1] * fx * (1 - fy)
            + tex[y1, x0] * (1 - fx) * fy + tex[y1, x1] * fx * fy)


def _noise(rng: np.random.Generator, size: int, scales=(4, 16, 64), weights=(0.5, 0.3, 0.2)) -> np.ndarray:
    import cv2

    out = np.zeros((size, size))
    for s, w in zip(scales, weights):
        small = rng.random((s, s))
        big = cv2.resize(np.tile(small, (2, 2)), (2 * size, 2 * size), interpolation=cv2.INTER_CUBIC)
        out += w * big[size // 2: size // 2 + size, size // 2: size // 2 + size]
    return out


def _floor_texture(rng: np.random.Generator, size: int = 1024) -> np.ndarray:
    """Paving/grass-like ground: tiles with noise (24 m across)."""
    n = _noise(rng, size)
    base = rng.choice([np.array([0.42, 0.5, 0.3]), np.array([0.55, 0.52, 0.48]), np.array([0.5, 0.45, 0.38])])
    tex = base[None, None] * (0.75 + 0.5 * n[..., None])
    yy, xx = np.mgrid[0:size, 0:size]
    tile = size // 40  # 0.6 m tiles
    grout = ((xx % tile) < 2) | ((yy % tile) < 2)
    tex[grout] *= 0.7
    return np.clip(tex, 0, 1)


def _wall_texture(rng: np.random.Generator, w: int = 2048, h: int = 256) -> np.ndarray:
    """Buildings and trees around the scene: coloured blocks with windows, noisy greens."""
    tex = np.zeros((h, w, 3))
    x = 0
    while x < w:
        bw = int(rng.integers(60, 220))
        top = int(rng.integers(h // 4, h))
        col = rng.uniform(0.3, 0.85, 3)
        if rng.random() < 0.35:  # tree
            col = np.array([0.2, 0.4, 0.15]) * rng.uniform(0.8, 1.3)
        tex[:top, x:x + bw] = col
        if rng.random() < 0.6:  # windows
            for wy in range(8, top - 10, 24):
                for wx in range(x + 6, min(x + bw - 10, w - 10), 22):
                    tex[wy:wy + 12, wx:wx + 10] = col * 0.45
        x += bw
    sky = tex.sum(-1) == 0
    tex[sky] = np.array([0.75, 0.82, 0.9])
    tex *= 0.85 + 0.3 * _noise(rng, max(w, h))[:h, :w, None]
    return np.clip(tex[::-1], 0, 1)  # row 0 = ground level


class CameraRenderer:
    """Renders frames of one camera; rays for every pixel are computed once."""

    def __init__(self, camera: Camera, env: Environment):
        self.camera = camera
        self.env = env
        w, h = camera.size
        yy, xx = np.mgrid[0:h, 0:w]
        self.pix_n2 = np.stack([xx.ravel(), yy.ravel()], 1).astype(np.float64)
        origin, dirs = camera.ray(self.pix_n2)
        self.origin = origin
        self.dirs = dirs  # (H*W, 3) unit world directions
        self.zdir = camera.R[2]  # optical axis in world: depth = t * (d . zdir)
        self.cos_z = dirs @ self.zdir
        self.ray_n2 = (dirs @ camera.R.T)[:, :2] / self.cos_z[:, None]  # each pixel's ray on the z = 1 plane
        self.props = PeopleScene(env.props) if env.props else None
        # the static part of the image (floor + background), shaded once without people
        self._static_rgb, self._static_depth = self._shade_static(np.arange(len(dirs)), np.zeros((0, 2)))

    def static_image(self) -> np.ndarray:
        """The empty scene (floor and background, no people) as float32 RGB 0..255 (H, W, 3):
        what the camera sees while the board is shown to it (a clean plate)."""
        w, h = self.camera.size
        return (self._static_rgb.reshape(h, w, 3) * 255.0).astype(np.float32)

    def _shade_static(self, idx: np.ndarray, blobs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Colour and z-depth of the floor, wall or sky and furniture seen by the pixels ``idx``
        (without people; ``blobs``: the people's floor positions, for their contact shadows)."""
        d = self.dirs[idx]
        C = self.origin
        rgb = np.empty((len(idx), 3))
        depth = np.full(len(idx), np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_floor = np.where(d[:, 2] < -1e-9, -C[2] / d[:, 2], np.inf)
        floor = np.isfinite(t_floor) & (t_floor < 60)
        if self.env.room:  # the floor ends at the wall
            floor &= ((C[:2] + t_floor[:, None] * d[:, :2]) ** 2).sum(1) <= self.env.radius ** 2
        X = C + t_floor[floor, None] * d[floor]
        rgb[floor] = self.env.shade_floor(X, blobs)
        depth[floor] = t_floor[floor] * self.cos_z[idx][floor]
        rgb[~floor], t_wall = self.env.shade_background(C, d[~floor])
        depth[~floor] = t_wall * self.cos_z[idx][~floor]
        if self.props is not None:  # furniture in front of floor and wall
            prim, tfar, u, v = self.props.cast(C, d)
            hit = prim >= 0
            z = np.where(hit, tfar * self.cos_z[idx], np.inf)
            near = hit & (z < depth)
            rgb[near] = self._shade_hits(self.props, idx[near], prim[near], u[near], v[near])
            depth[near] = z[near]
        return rgb, depth

    def _shade_hits(self, scene: "PeopleScene", pix, prim, u, v) -> np.ndarray:
        """Colours (N, 3) of mesh surface points hit by the rays of pixels ``pix``."""
        f = scene.faces[prim]
        bary = np.stack([1 - u - v, u, v], 1)[..., None]
        col = (scene.colors[f] * bary).sum(1)
        n = (scene.normals[f] * bary).sum(1)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)
        lam = np.clip(n @ self.env.sun, 0, None)
        # a little light from the camera side keeps silhouettes readable
        rim = 0.15 * np.clip(-(n * self.dirs[pix]).sum(1), 0, 1)
        shade = self.env.ambient + (1 - self.env.ambient) * lam + rim
        return col * shade[:, None]

    def render(self, people: list[PersonMesh], rng: np.random.Generator | None = None, noise: float = 0.0,
               points_by_person: list[np.ndarray] | None = None,
               scene: "PeopleScene | None" = None, light_h: np.ndarray | None = None
               ) -> tuple[Frame, list[np.ndarray] | None]:
        """Render one frame; with ``points_by_person`` also return their visibility
        (see :func:`point_visibility`) from the same ray-casting scene. Pass ``scene`` to
        reuse one built for the same people (several views of one instant). ``light_h``: a
        factor per image row on every lit surface (floor and people; a flash, see
        :func:`flash_rows`), applied before the sensor noise."""
        w, h = self.camera.size
        rgb = self._static_rgb.copy()
        depth = self._static_depth.copy()
        inst = np.full(w * h, -1, np.int16)
        vis = None
        if people:
            scene = scene or PeopleScene(people)
            blobs = np.array([p.verts[:, :2].mean(0) for p in people])
            box_idx = self._people_pixels(people)
            if len(box_idx):
                # floor under people gets its contact shadow; then people over it
                rgb[box_idx], _ = self._shade_static(box_idx, blobs)
                self._cast_people(scene, box_idx, rgb, depth, inst)
            if points_by_person is not None:
                vis = scene.visibility(self.camera, points_by_person)
                # what the image shows: the landmark's nearest pixel must be its person's
                # (thin parts such as fingers can be unoccluded yet miss every pixel centre)
                inst2 = inst.reshape(h, w)
                for p, pts in enumerate(points_by_person):
                    uv = np.round(self.camera.project(pts))
                    ok = np.isfinite(uv).all(1)
                    x = np.clip(np.nan_to_num(uv[:, 0]), 0, w - 1).astype(int)
                    y = np.clip(np.nan_to_num(uv[:, 1]), 0, h - 1).astype(int)
                    vis[p] = vis[p] & ok & (inst2[y, x] == p)
        img = rgb.reshape(h, w, 3)
        if light_h is not None:
            img = np.where(np.isfinite(depth).reshape(h, w, 1), img * light_h[:, None, None], img)
        if rng is not None and noise > 0:
            img = img + rng.normal(0, noise / 255.0, img.shape)
        img8 = np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)
        return Frame(img8, inst.reshape(h, w), depth.reshape(h, w).astype(np.float32)), vis

    def _people_pixels(self, people: list[PersonMesh]) -> np.ndarray:
        """Indices of pixels whose rays pass through the (padded) boxes of all people, the boxes
        taken on the camera's undistorted image plane: a lens model's pixels are only defined
        inside its field of view, and a body beside or at the camera reaches far outside it."""
        cam = self.camera
        mask = np.zeros(len(self.dirs), bool)
        pad_n = 4.0 / min(cam.K[0, 0], cam.K[1, 1])  # four pixels on the image plane
        for p in people:
            Xc_n3 = (p.verts[:: max(1, len(p.verts) // 3000)] - cam.center) @ cam.R.T
            if (Xc_n3[:, 2] <= 0).all():
                continue
            if (Xc_n3[:, 2] <= 1e-3).any():  # part of the body at or behind the lens: any ray may hit it
                return np.arange(len(self.dirs))
            xy_n2 = Xc_n3[:, :2] / Xc_n3[:, 2:]
            lo, hi = xy_n2.min(0), xy_n2.max(0)
            pad = 0.08 * (hi - lo).max() + pad_n
            mask |= ((self.ray_n2 >= lo - pad) & (self.ray_n2 <= hi + pad)).all(1)
        return np.flatnonzero(mask)

    def _cast_people(self, scene: "PeopleScene", idx, rgb, depth, inst) -> None:
        prim, tfar, u, v = scene.cast(self.origin, self.dirs[idx])
        hit = prim >= 0
        pix, prim, tfar, u, v = idx[hit], prim[hit], tfar[hit], u[hit], v[hit]
        z = tfar * self.cos_z[pix]
        closer = z < depth[pix]
        pix, prim, z, u, v = pix[closer], prim[closer], z[closer], u[closer], v[closer]
        rgb[pix] = self._shade_hits(scene, pix, prim, u, v)
        depth[pix] = z
        inst[pix] = scene.face_person[prim]


def flash_rows(clock, t_frame: float, height: int, exposure_s: float, readout_s: float, on_s: np.ndarray,
               off_s: np.ndarray, gain: float, gamma: float = 2.2) -> np.ndarray:
    """Per image row (H,): the factor a flash puts on the frame stamped ``t_frame`` (camera clock).

    Row y (in [0, 1]) integrates the light over [tau - e/2, tau + e/2], tau = t_frame + (y - 1/2) R
    (exposure e, rolling-shutter readout R), mapped to scene time by ``clock``; the light is on
    over [on_s[i], off_s[i]) in scene time. The added light is linear (gain times the lit fraction
    of the exposure) and the image is gamma encoded, so the factor on display values is
    (1 + gain f)^(1/gamma)."""
    y_h = (np.arange(height) + 0.5) / height
    tau_h = t_frame + (y_h - 0.5) * readout_s
    a_h, b_h = clock.to_ref(tau_h - 0.5 * exposure_s), clock.to_ref(tau_h + 0.5 * exposure_s)
    if exposure_s > 0:
        lit_h = np.clip(np.minimum(b_h[:, None], off_s[None]) - np.maximum(a_h[:, None], on_s[None]), 0, None).sum(1) \
            / (b_h - a_h)
    else:
        lit_h = ((a_h[:, None] >= on_s[None]) & (a_h[:, None] < off_s[None])).any(1).astype(float)
    return (1.0 + gain * lit_h) ** (1.0 / gamma)


_DEVICE = None


def _device():
    """One embree device per process (creating one per scene costs ~0.1 s)."""
    global _DEVICE
    if _DEVICE is None:
        from embreex import rtcore

        _DEVICE = rtcore.EmbreeDevice()
    return _DEVICE


class PeopleScene:
    """All people of one frame in one embree scene: ray casts with distance and barycentrics."""

    def __init__(self, people: list[PersonMesh]):
        from embreex import mesh_construction, rtcore_scene

        verts, faces, cols, owner = [], [], [], []
        off = 0
        for i, p in enumerate(people):
            verts.append(p.verts)
            faces.append(p.faces + off)
            cols.append(p.colors)
            owner.append(np.full(len(p.faces), i, np.int16))
            off += len(p.verts)
        self.verts = np.concatenate(verts).astype(np.float64)
        self.faces = np.concatenate(faces).astype(np.int64)
        self.colors = np.concatenate(cols)
        self.face_person = np.concatenate(owner)
        self.normals = vertex_normals(self.verts, self.faces)
        self._scene = rtcore_scene.EmbreeScene(_device())
        mesh_construction.TriangleMesh(self._scene, self.verts.astype(np.float32), self.faces.astype(np.int32))

    def cast(self, origin: np.ndarray, dirs_n3: np.ndarray):
        """First hits of rays from one origin: (prim id or -1, distance, u, v)."""
        o = np.broadcast_to(np.asarray(origin, np.float32), dirs_n3.shape).copy()
        r = self._scene.run(o, np.ascontiguousarray(dirs_n3, np.float32), output=1)
        return r["primID"], r["tfar"].astype(np.float64), r["u"].astype(np.float64), r["v"].astype(np.float64)

    def visibility(self, camera: Camera, points_by_person: list[np.ndarray], tol: float = 0.02) -> list[np.ndarray]:
        """True where no surface lies on the ray from the camera to a point (a vertex on a
        person's surface) nearer than ``tol`` m before it, and the point projects inside
        the image. (A ray aimed exactly at a vertex can slip past its own surface at grazing
        angles; nothing in front of it still means visible.)"""
        C = camera.center
        pts = np.concatenate(points_by_person)
        v = pts - C
        dist = np.linalg.norm(v, axis=1)
        prim, tfar, _, _ = self.cast(C, v / dist[:, None])
        ok = ~((prim >= 0) & (tfar < dist - tol))
        w, h = camera.size
        uv = camera.project(pts)
        inside = np.isfinite(uv).all(1) & (uv[:, 0] >= -0.5) & (uv[:, 0] < w - 0.5) & \
            (uv[:, 1] >= -0.5) & (uv[:, 1] < h - 0.5)
        vis = ok & inside
        return np.split(vis, np.cumsum([len(q) for q in points_by_person])[:-1])


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (V, 3)."""
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n = np.zeros_like(V)
    for k in range(3):
        for c in range(3):
            n[:, c] += np.bincount(F[:, k], fn[:, c], minlength=len(V))
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def point_visibility(camera: Camera, people: list[PersonMesh], points_by_person: list[np.ndarray],
                     tol: float = 0.02) -> list[np.ndarray]:
    """Visibility of points on people's surfaces from a camera (see PeopleScene.visibility)."""
    return PeopleScene(people).visibility(camera, points_by_person, tol)
