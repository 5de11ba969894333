"""People's looks: skin tones and clothing per body part, with procedural patterns that
move with the body (computed on rest-pose coordinates)."""

from __future__ import annotations

import numpy as np

SKIN_TONES = np.array([
    [0.98, 0.84, 0.72], [0.93, 0.75, 0.62], [0.85, 0.64, 0.5], [0.72, 0.52, 0.38],
    [0.55, 0.38, 0.26], [0.42, 0.28, 0.2], [0.32, 0.22, 0.16],
])
GARMENT_COLOURS = np.array([
    [0.85, 0.15, 0.15], [0.15, 0.35, 0.8], [0.1, 0.55, 0.25], [0.95, 0.8, 0.2], [0.95, 0.95, 0.95],
    [0.1, 0.1, 0.12], [0.55, 0.3, 0.65], [0.95, 0.5, 0.15], [0.4, 0.4, 0.45], [0.2, 0.65, 0.75],
    [0.6, 0.45, 0.3], [0.9, 0.6, 0.7],
])

# which garment covers each body part name (parts from the body model's vertex labels)
SLEEVES = {"short": ("torso", "upper_arm"), "long": ("torso", "upper_arm", "lower_arm")}


def person_colors(rest_verts_v3: np.ndarray, vertex_part_names: list[str], rng: np.random.Generator,
                  override: dict | None = None) -> np.ndarray:
    """Per-vertex RGB (V, 3) in [0, 1] for one person.

    ``vertex_part_names``: the part name of every vertex (head, torso, upper_arm, lower_arm,
    hand, upper_leg, lower_leg, foot, ...; left/right prefixes are ignored).
    """
    override = override or {}
    parts = np.array([p.replace("left_", "").replace("right_", "") for p in vertex_part_names])
    skin = np.asarray(override.get("skin", SKIN_TONES[rng.integers(len(SKIN_TONES))]), float)
    top = np.asarray(override.get("top", GARMENT_COLOURS[rng.integers(len(GARMENT_COLOURS))]), float)
    bottom = np.asarray(override.get("bottom", GARMENT_COLOURS[rng.integers(len(GARMENT_COLOURS))]), float)
    shoes = np.asarray(override.get("shoes", GARMENT_COLOURS[rng.integers(len(GARMENT_COLOURS))] * 0.5), float)
    hair = np.array([0.1, 0.07, 0.05]) * rng.uniform(0.7, 3.0)
    sleeves = SLEEVES[override.get("sleeves", rng.choice(["short", "long"]))]
    shorts = bool(override.get("shorts", rng.random() < 0.25))
    V = len(rest_verts_v3)
    col = np.repeat(skin[None], V, 0)
    y = rest_verts_v3[:, 1]
    # top garment with a pattern: stripes, checks or plain
    pattern = override.get("pattern", rng.choice(["plain", "stripes", "checks", "gradient"]))
    on_top = np.isin(parts, sleeves)
    t = np.ones(V)
    if pattern == "stripes":
        t = 0.75 + 0.25 * (np.sin(y * rng.uniform(40, 90)) > 0)
    elif pattern == "checks":
        x, z = rest_verts_v3[:, 0], rest_verts_v3[:, 2]
        t = 0.75 + 0.25 * ((np.sin(y * 45) > 0) ^ (np.sin((x + z) * 45) > 0))
    elif pattern == "gradient":
        t = 0.7 + 0.3 * (y - y.min()) / max(np.ptp(y), 1e-6)
    col[on_top] = top * t[on_top, None]
    legs = np.isin(parts, ("upper_leg",) if shorts else ("upper_leg", "lower_leg", "hips"))
    col[legs] = bottom
    col[np.isin(parts, ("hips", "pelvis"))] = bottom
    col[parts == "foot"] = shoes
    # hair: the top/back of the head
    head = parts == "head"
    if head.any():
        hy = y[head]
        top_of_head = hy > hy.min() + 0.72 * np.ptp(hy)
        back = rest_verts_v3[head, 2] < np.median(rest_verts_v3[head, 2]) - 0.02
        hair_mask = np.zeros(V, bool)
        hair_mask[np.flatnonzero(head)] = top_of_head | (back & (hy > hy.min() + 0.35 * np.ptp(hy)))
        col[hair_mask] = hair
    # subtle cloth/skin noise so surfaces are not flat
    col *= (0.92 + 0.08 * np.sin(rest_verts_v3 @ rng.normal(0, 30, 3)))[:, None]
    return np.clip(col, 0, 1)
