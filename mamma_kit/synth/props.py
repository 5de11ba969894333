"""Furniture for synthetic scenes: office chairs and tables built from trimesh primitives, placed
where nobody walks, so a tracker meets the clutter of a real room (dark chairs with a person's
height and width, table edges that hide legs).

A recipe asks for them in ``[scene]``::

    [scene]
    chairs = 6                  # office chairs (seat, back, column, five-star base)
    tables = 2                  # tables (top and four legs)
    room_radius_m = 6.5         # the wall around the scene (default 14: an outdoor backdrop)
    doors_deg = [45.0, 225.0]   # doorways in the wall (azimuth); `wander` people leave through them

Props are static: each camera renders them once into its empty-scene image (with depth), so
people behind them are hidden and the board session shows them too.
"""

from __future__ import annotations

import numpy as np

from mamma_kit.synth.render import PersonMesh

CHAIR_COLOURS = np.array([[0.08, 0.08, 0.09], [0.12, 0.12, 0.14], [0.2, 0.22, 0.3], [0.3, 0.3, 0.32]])
TABLE_COLOURS = np.array([[0.55, 0.4, 0.25], [0.85, 0.85, 0.82], [0.35, 0.25, 0.18], [0.6, 0.6, 0.62]])
CLEARANCE_M = 0.75  # a prop's centre stays this far from every person's path (their half-width + its own)


def _box(extents, centre, yaw: float = 0.0):
    import trimesh

    m = trimesh.creation.box(extents=extents)
    m.apply_translation(centre)
    if yaw:
        m.apply_transform(trimesh.transformations.rotation_matrix(yaw, [0, 0, 1]))
    return m


def chair_mesh(rng: np.random.Generator):
    """An office chair about 0.95-1.15 m tall, seat at 0.45 m, centred on the origin, facing +x."""
    import trimesh

    seat_h = rng.uniform(0.42, 0.5)
    w = rng.uniform(0.44, 0.52)
    back_h = rng.uniform(0.5, 0.65)
    parts = [_box([w, w, 0.08], [0, 0, seat_h]),  # seat cushion
             _box([0.06, w * 0.95, back_h], [-w / 2 + 0.03, 0, seat_h + 0.08 + back_h / 2]),  # back
             trimesh.creation.cylinder(radius=0.03, height=seat_h - 0.08, sections=12,
                                       transform=trimesh.transformations.translation_matrix(
                                           [0, 0, 0.08 + (seat_h - 0.08) / 2]))]
    for k in range(5):  # five-star base
        a = 2 * np.pi * k / 5
        parts.append(_box([0.32, 0.05, 0.04], [0.16, 0, 0.06], 0.0).apply_transform(
            trimesh.transformations.rotation_matrix(a, [0, 0, 1])))
        parts.append(trimesh.creation.icosphere(1, radius=0.03).apply_translation(
            [0.3 * np.cos(a), 0.3 * np.sin(a), 0.03]))
    if rng.random() < 0.7:  # arm rests
        for s in (-1, 1):
            parts.append(_box([w * 0.7, 0.05, 0.04], [0, s * (w / 2 + 0.02), seat_h + 0.24]))
            parts.append(_box([0.04, 0.04, 0.22], [0.05, s * (w / 2 + 0.02), seat_h + 0.12]))
    return trimesh.util.concatenate(parts)


def table_mesh(rng: np.random.Generator):
    """A table 1.2-1.8 x 0.7-0.9 m with its top at 0.72-0.76 m, centred on the origin."""
    import trimesh

    L, W, H = rng.uniform(1.2, 1.8), rng.uniform(0.7, 0.9), rng.uniform(0.72, 0.76)
    parts = [_box([L, W, 0.035], [0, 0, H - 0.0175])]
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(_box([0.05, 0.05, H - 0.035], [sx * (L / 2 - 0.06), sy * (W / 2 - 0.06), (H - 0.035) / 2]))
    return trimesh.util.concatenate(parts)


def _coloured(mesh, colour: np.ndarray, rng: np.random.Generator) -> PersonMesh:
    """Faces unshared (flat shading of boxes), one colour with a little per-vertex variation."""
    mesh = mesh.copy()
    mesh.unmerge_vertices()
    v = np.asarray(mesh.vertices, float)
    col = np.clip(colour[None] * rng.uniform(0.9, 1.1, (len(v), 1)), 0, 1)
    return PersonMesh(v, np.asarray(mesh.faces, np.int64), col)


def place_props(n_chairs: int, n_tables: int, rng: np.random.Generator, paths_pn2: np.ndarray,
                cameras_c2: np.ndarray, room_radius: float) -> list[PersonMesh]:
    """Chairs and tables at random places and headings inside the room, none within CLEARANCE_M of
    any person's path (paths_pn2: the people's pelvis positions over time, (P, N, 2)) or 1 m of a
    camera (cameras_c2), nor overlapping each other. Fewer are placed when the room is full."""
    path_pts = paths_pn2.reshape(-1, 2)[:: max(1, paths_pn2.size // 2 // 4000)]
    placed: list[tuple[np.ndarray, float]] = []
    out: list[PersonMesh] = []
    kinds = ["table"] * n_tables + ["chair"] * n_chairs  # tables first: they need the most room
    r_max = min(room_radius - 0.6, 8.0)
    for kind in kinds:
        size = 0.95 if kind == "table" else 0.4
        for _ in range(400):
            r, a = r_max * np.sqrt(rng.uniform(0.02, 1.0)), rng.uniform(0, 2 * np.pi)
            xy = np.array([r * np.cos(a), r * np.sin(a)])
            if len(path_pts) and np.min(np.linalg.norm(path_pts - xy, axis=1)) < CLEARANCE_M + size - 0.3:
                continue
            if len(cameras_c2) and np.min(np.linalg.norm(cameras_c2 - xy, axis=1)) < 1.0 + size:
                continue
            if any(np.linalg.norm(xy - q) < size + s for q, s in placed):
                continue
            break
        else:
            continue
        yaw = rng.uniform(0, 2 * np.pi)
        if kind == "chair":
            mesh, colour = chair_mesh(rng), CHAIR_COLOURS[rng.integers(len(CHAIR_COLOURS))]
        else:
            mesh, colour = table_mesh(rng), TABLE_COLOURS[rng.integers(len(TABLE_COLOURS))]
        import trimesh

        mesh.apply_transform(trimesh.transformations.rotation_matrix(yaw, [0, 0, 1]))
        mesh.apply_translation([xy[0], xy[1], 0.0])
        out.append(_coloured(mesh, colour, rng))
        placed.append((xy, size))
    return out
