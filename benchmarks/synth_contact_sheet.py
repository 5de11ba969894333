"""A contact sheet of the synthetic captures: one row per recipe in recipes/.

    nice -n 10 .venv/bin/python benchmarks/synth_contact_sheet.py            # -> docs/synth-contact-sheet.png

Each recipe is rendered cheaply with `synthesize` (--frames frames of action, at --scale of
its resolution but never below --tile px wide, no board session), then one instant of the
action (scene time frames / fps / 2) is read from up to --cameras views (spread over the rig;
a recipe with more cameras is rendered with only those, at their exact poses and lenses) and
tiled, each tile labelled with recipe and camera. The first view of the first recipe with two
or more people is repeated with the ground-truth instance masks (gt/masks) overlaid in colour.
A recipe without people (board-only) is a calibration session: only its board session is
rendered (synthesize's board step; --board-seconds shortens it) and
its row shows each camera's board video at the frame where the board fills most of the image.
Tiles are --tile px wide; the sheet is a PNG, colour-quantised if it would exceed --max-mb.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ("tiny", "iphone-outdoor-duo", "studio-16cam-solo", "crowd-6", "board-only")
# instance colours (RGB), one per person, as in the tracks pictures
COLOURS = np.array([(230, 25, 75), (60, 180, 75), (255, 225, 25), (0, 130, 200), (245, 130, 48),
                    (145, 30, 180), (70, 240, 240), (240, 50, 230)], np.float32)


def _subset_recipe(name: str, n_cams: int, board_s: float | None, dst: Path) -> tuple[Path, list[str]]:
    """A copy of a recipe with at most ``n_cams`` of its cameras (evenly spread, at their exact
    poses, lenses and resolutions: written as an explicit rig) and, for board sessions,
    ``board_s`` seconds. Returns the recipe path and the chosen camera names."""
    from mamma_kit.core.io import write_toml
    from mamma_kit.synth.recipe import load_recipe

    r = load_recipe(name)
    pick = np.unique(np.linspace(0, len(r.cameras), min(n_cams, len(r.cameras)), endpoint=False).astype(int))
    cams = [r.cameras[i] for i in pick]
    data = dict(r.raw)
    rig = {k: v for k, v in data.get("rig", {}).items() if k in ("clock", "distortion", "resolution")}
    rig["preset"] = "explicit"
    rig["cameras"] = [{"name": c.name, "position": [float(x) for x in c.position],
                       "look_at": [float(x) for x in c.look_at], "resolution": [int(x) for x in c.resolution],
                       "focal_px": float(c.focal_px), "distortion": [float(x) for x in c.distortion],
                       "portrait": bool(c.portrait), **({"clock": c.clock} if c.clock else {})} for c in cams]
    data["rig"] = rig
    if board_s is not None and data.get("board") is not None:
        data["board"] = dict(data["board"]) | {"duration_s": float(board_s)}
    path = dst / f"{name}.toml"
    write_toml(path, data)
    return path, [c.name for c in cams]


def _label(img: np.ndarray, lines: list[str]) -> np.ndarray:
    """White text on a dark band at the top-left (first line larger), readable on any
    background and still when the sheet is shown at half size."""
    img = img.copy()
    font = cv2.FONT_HERSHEY_SIMPLEX
    sizes = [0.52] + [0.42] * (len(lines) - 1)
    steps = [round(30 * fs) for fs in sizes]
    w = max(cv2.getTextSize(s, font, fs, 1)[0][0] for s, fs in zip(lines, sizes)) + 8
    hb = sum(steps) + 6
    img[:hb, :w] = (img[:hb, :w].astype(np.float32) * 0.3).astype(np.uint8)
    y = 0
    for s, fs, st in zip(lines, sizes, steps):
        y += st
        cv2.putText(img, s, (4, y - 2), font, fs, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def _fit(img: np.ndarray, width: int) -> np.ndarray:
    h, w = img.shape[:2]
    return cv2.resize(img, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)


def _overlay(rgb: np.ndarray, masks: list[tuple[int, np.ndarray]]) -> np.ndarray:
    out = rgb.astype(np.float32)
    for pid, m in masks:
        c = COLOURS[pid % len(COLOURS)]
        out[m] = 0.45 * out[m] + 0.55 * c
        edge = m & ~cv2.erode(m.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        out[edge] = c
    return np.clip(out, 0, 255).astype(np.uint8)


def _board_frame(path: Path) -> tuple[int, np.ndarray]:
    """The frame of a board video where the board (a black/white checker pattern) covers the
    most of the image: scored by the count of strong, colourless edges, on every 5th frame."""
    from mamma_kit.video.reader import VideoReader

    rd = VideoReader(path)
    best = (-1.0, 0, None)
    for i, _, rgb in rd.read_indices(range(0, rd.n_frames, 5)):
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        grey = hsv[..., 2].astype(np.float32)
        edges = np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0)) + np.abs(cv2.Sobel(grey, cv2.CV_32F, 0, 1))
        score = float(((edges > 200) & (hsv[..., 1] < 40)).mean())
        if score > best[0]:
            best = (score, i, rgb)
    return best[1], best[2]


def _board_session(recipe_path: Path, out: Path, seed: int | None, scale: float):
    """Only the calibration session of a recipe, exactly as `synthesize` renders it (its
    rig, scene and board step; `synthesize` itself stops at the people videos of a recipe
    without people)."""
    from mamma_kit.synth import capture
    from mamma_kit.synth.recipe import load_recipe
    from mamma_kit.synth.rig import build_rig
    from mamma_kit.synth.scene import build_scene

    r = load_recipe(recipe_path, seed)
    r.render["scale"] = scale
    cams = build_rig(r)
    return cams, capture._render_board(r, cams, out, build_scene(r, cams))


def render_rows(recipes, work: Path, frames: int, scale: float, n_cams: int, board_s: float, tile: int,
                seed: int | None) -> list[list[np.ndarray]]:
    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.synth.capture import synthesize
    from mamma_kit.synth.recipe import load_recipe
    from mamma_kit.video.reader import VideoReader

    rows, masked_done = [], False
    for name in recipes:
        r = load_recipe(name)
        has_people = r.people_count > 0
        sc_r = min(1.0, max(scale, tile / max(c.resolution[0] for c in r.cameras)))
        rpath, names = _subset_recipe(name, n_cams, None if has_people else board_s, work)
        t0, c0 = time.perf_counter(), time.process_time()
        if has_people:
            res = synthesize(rpath, work / name, seed=seed, frames=frames, scale=sc_r, board=False)
            cams, videos, what = res.cameras, res.paths["videos"], f"{frames} frames of action"
        else:
            cams, videos = _board_session(rpath, work / name, seed, sc_r)
            what = f"board session of {float(load_recipe(rpath).board['duration_s']):g} s"
        size = cams[0].camera.size
        print(f"{name}: {len(names)} cameras ({', '.join(names)}) at {size[0]}x{size[1]} (scale {sc_r:.3g}), "
              f"{what}: {time.perf_counter() - t0:.1f} s wall, {time.process_time() - c0:.1f} s CPU", flush=True)
        row = []
        for sc in cams:
            cam = sc.camera.name
            if has_people:
                k = int(np.argmin(np.abs(sc.scene_times - res.recipe.duration_s / 2)))
                t, rgb = VideoReader(work / name / videos[cam]).frame_index(k)
                lines = [f"{name}  {cam}", f"{size[0]}x{size[1]}  frame {k}  scene t {sc.scene_times[k]:.2f} s"]
            else:
                k, rgb = _board_frame(work / name / videos[cam])
                lines = [f"{name}  {cam}  board video", f"{size[0]}x{size[1]}  frame {k}"]
            row.append(_label(_fit(rgb, tile), lines))
        if has_people and res.recipe.people_count >= 2 and not masked_done:
            sc = res.cameras[0]
            k = int(np.argmin(np.abs(sc.scene_times - res.recipe.duration_s / 2)))
            _, rgb = VideoReader(work / name / res.paths["videos"][sc.camera.name]).frame_index(k)
            mt = MaskTracks.load(work / name / "gt" / "masks" / f"{sc.camera.name}.npz")
            masks = [(int(pid), m) for j, pid in enumerate(mt.track_ids) if (m := mt.mask(k, j)) is not None]
            row.append(_label(_fit(_overlay(rgb, masks), tile),
                              [f"{name}  {sc.camera.name}", f"gt instance masks ({len(masks)} people)"]))
            masked_done = True
        rows.append(row)
    return rows


def assemble(rows: list[list[np.ndarray]], tile: int, gap: int = 4) -> np.ndarray:
    n_cols = max(len(r) for r in rows)
    heights = [max(t.shape[0] for t in r) for r in rows]
    W = n_cols * tile + (n_cols + 1) * gap
    H = sum(heights) + (len(rows) + 1) * gap
    sheet = np.full((H, W, 3), 24, np.uint8)
    y = gap
    for r, h in zip(rows, heights):
        x = gap
        for t in r:
            sheet[y + (h - t.shape[0]) // 2: y + (h - t.shape[0]) // 2 + t.shape[0], x:x + t.shape[1]] = t
            x += tile + gap
        y += h + gap
    return sheet


def write_png(sheet: np.ndarray, out: Path, max_mb: float) -> str:
    out.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    how = "RGB"
    if len(buf) > max_mb * 1e6:  # rendered noise compresses badly: a 256-colour palette PNG
        from PIL import Image  # Pillow comes with matplotlib

        im = Image.fromarray(sheet).quantize(colors=256, method=Image.Quantize.MEDIANCUT,
                                             dither=Image.Dither.NONE)
        tmp = out.with_suffix(".tmp.png")
        im.save(tmp, optimize=True)
        tmp.replace(out)
        return "256-colour palette"
    tmp = out.with_suffix(".tmp.png")
    tmp.write_bytes(buf.tobytes())
    tmp.replace(out)
    return how


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recipe", action="append", help=f"recipes to show (default: {', '.join(RECIPES)})")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--scale", type=float, default=0.25)
    ap.add_argument("--cameras", type=int, default=4, help="views per recipe (recipes with more cameras "
                                                          "are rendered with only these)")
    ap.add_argument("--board-seconds", type=float, default=None, help="board session length for recipes "
                                                                     "without people (default: the recipe's)")
    ap.add_argument("--tile", type=int, default=320, help="tile width in px")
    ap.add_argument("--max-mb", type=float, default=1.5)
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--work", type=Path, default=None, help="keep the rendered workspaces here "
                                                            "(default: a temp dir, deleted)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "synth-contact-sheet.png")
    a = ap.parse_args()
    recipes = a.recipe or list(RECIPES)
    print("command: " + " ".join(sys.argv))
    work = a.work or Path(tempfile.mkdtemp(prefix="synth_sheet_"))
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        rows = render_rows(recipes, work, a.frames, a.scale, a.cameras, a.board_seconds, a.tile, a.seed)
    finally:
        if a.work is None:
            shutil.rmtree(work, ignore_errors=True)
    sheet = assemble(rows, a.tile)
    how = write_png(sheet, a.out, a.max_mb)
    print(f"wrote {a.out} ({sheet.shape[1]}x{sheet.shape[0]}, {how}, {a.out.stat().st_size / 1e6:.2f} MB) "
          f"in {time.perf_counter() - t0:.0f} s")
    print("reproduce: " + " ".join(["nice -n 10 .venv/bin/python benchmarks/synth_contact_sheet.py", *sys.argv[1:]]))


if __name__ == "__main__":
    main()
