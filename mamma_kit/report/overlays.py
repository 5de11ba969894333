"""Fitted meshes drawn over the capture videos: stills per camera and one short video.

The mesh is projected with the camera's lens model (``Camera.project``) and rasterised by
a vectorised z-buffer: every triangle's candidate pixels (pixel centres inside its bounding
box) are tested with edge functions in one numpy pass per bounding-box size class, depth is
interpolated barycentrically, and the nearest triangle wins each pixel. Triangles are shaded
by the angle between their normal and the viewing ray, one colour per person, and blended
over the frame.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mamma_kit.core.io import atomic_write_bytes
from mamma_kit.core.colour import person_colour
from mamma_kit.report.data import ReportData

ALPHA = 0.6  # mesh opacity over the video
MAX_CANDIDATES = 2_000_000  # candidate pixels per rasterisation batch (bounds memory)
STILLS_PER_CAMERA = 4
STILLS_WIDTH = 1120  # px: the page's content width
VIDEO_WIDTH = 640
VIDEO_SECONDS = 3.0
VIDEO_CAMERAS = 4


def rasterize(xy_f32: np.ndarray, z_f3: np.ndarray, size_wh: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer F triangles with pixel corners xy (F, 3, 2) and camera depths z (F, 3) into a
    (H, W) image. Returns the winning triangle per pixel (H, W) int (-1: none) and its depth."""
    W, H = int(size_wh[0]), int(size_wh[1])
    face_hw = np.full(H * W, -1, np.int64)
    depth_hw = np.full(H * W, np.inf)
    # triangles behind the camera or with unprojectable corners are dropped up front
    tri = np.flatnonzero(np.isfinite(xy_f32).all((1, 2)) & (z_f3 > 0).all(1))
    xy = np.clip(xy_f32[tri], -1e6, 1e6)
    inv_z = 1.0 / z_f3[tri]  # 1/z is linear in screen space: exact depth inside a triangle
    lo = np.maximum(np.ceil(xy.min(1)).astype(np.int64), 0)  # first pixel centre in the bounding box
    hi = np.minimum(np.floor(xy.max(1)).astype(np.int64), [W - 1, H - 1])
    ext = (hi - lo).max(1) + 1  # bounding box side in pixels (<= 0: no pixel centre inside)
    a, b, c = xy[:, 0], xy[:, 1], xy[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep = (ext > 0) & (np.abs(area) > 1e-9)
    size_class = np.ceil(np.log2(np.maximum(ext, 1))).astype(np.int64)
    pix, inv, fid = [], [], []
    for k in np.unique(size_class[keep]):  # a few size classes: 1, 2, 4, ... px
        side = 1 << int(k)
        ids = np.flatnonzero(keep & (size_class == k))
        oy, ox = np.divmod(np.arange(side * side), side)
        step = max(1, MAX_CANDIDATES // (side * side))
        for s in range(0, len(ids), step):
            f = ids[s:s + step]
            px = lo[f, 0, None] + ox  # (n, side^2) candidate pixel centres
            py = lo[f, 1, None] + oy
            inbox = (px <= hi[f, 0, None]) & (py <= hi[f, 1, None])
            A, B, C = a[f], b[f], c[f]
            # barycentric weights from edge functions, normalised by the signed area
            w0 = ((B[:, 0, None] - px) * (C[:, 1, None] - py) - (B[:, 1, None] - py) * (C[:, 0, None] - px))
            w1 = ((C[:, 0, None] - px) * (A[:, 1, None] - py) - (C[:, 1, None] - py) * (A[:, 0, None] - px))
            w0, w1 = w0 / area[f, None], w1 / area[f, None]
            w2 = 1.0 - w0 - w1
            inside = inbox & (w0 >= -1e-6) & (w1 >= -1e-6) & (w2 >= -1e-6)
            iz = inv_z[f]
            r, q = np.nonzero(inside)
            pix.append(py[r, q] * W + px[r, q])
            inv.append(w0[r, q] * iz[r, 0] + w1[r, q] * iz[r, 1] + w2[r, q] * iz[r, 2])
            fid.append(tri[f[r]])
    if pix:
        pix, inv, fid = np.concatenate(pix), np.concatenate(inv), np.concatenate(fid)
        order = np.lexsort((-inv, pix))  # by pixel, nearest (largest 1/z) first
        first = np.r_[True, pix[order][1:] != pix[order][:-1]]
        win = order[first]
        face_hw[pix[win]] = fid[win]
        depth_hw[pix[win]] = 1.0 / inv[win]
    return face_hw.reshape(H, W), depth_hw.reshape(H, W)


def draw_meshes(rgb_hw3: np.ndarray, cam, scale: float, meshes: list[tuple[np.ndarray, tuple]],
                faces_f3: np.ndarray) -> np.ndarray:
    """Blend shaded meshes (world vertices (V, 3), RGB colour in [0, 1]) over an image that is the
    camera's frame resized by ``scale``."""
    if not meshes:
        return rgb_hw3
    H, W = rgb_hw3.shape[:2]
    xy, z, rgb = [], [], []
    for V_v3, colour in meshes:
        Xc_v3 = cam.to_camera(V_v3)
        xy_v2 = cam.project(V_v3) * scale + 0.5 * (scale - 1)  # pixel centres stay centres when resized
        tri_c = Xc_v3[faces_f3]  # (F, 3, 3)
        n_f3 = np.cross(tri_c[:, 1] - tri_c[:, 0], tri_c[:, 2] - tri_c[:, 0])
        ray_f3 = tri_c.mean(1)
        cos = np.abs((n_f3 * ray_f3).sum(1)) / np.maximum(np.linalg.norm(n_f3, axis=1) *
                                                         np.linalg.norm(ray_f3, axis=1), 1e-12)
        shade = 0.25 + 0.75 * cos
        xy.append(xy_v2[faces_f3])
        z.append(Xc_v3[:, 2][faces_f3])
        rgb.append(shade[:, None] * np.asarray(colour, float)[None] * 255)
    face_hw, _ = rasterize(np.concatenate(xy), np.concatenate(z), (W, H))
    hit = face_hw >= 0
    out = rgb_hw3.copy()
    col = np.concatenate(rgb)[face_hw[hit]]
    out[hit] = np.clip((1 - ALPHA) * rgb_hw3[hit] + ALPHA * col, 0, 255).astype(np.uint8)
    return out


def _label(img: np.ndarray, text: str) -> np.ndarray:
    s = max(0.35, img.shape[1] / 900)
    th = max(1, int(round(s * 2)))
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, s, th)
    cv2.rectangle(img, (0, 0), (w + 8, h + base + 6), (0, 0, 0), -1)
    cv2.putText(img, text, (4, h + 4), cv2.FONT_HERSHEY_SIMPLEX, s, (255, 255, 255), th, cv2.LINE_AA)
    return img


def _grid(tiles: list[np.ndarray], cols: int) -> np.ndarray:
    """Tiles of equal size into rows of ``cols`` (black where a row is short)."""
    th, tw = tiles[0].shape[:2]
    rows = -(-len(tiles) // cols)
    out = np.zeros((rows * th, cols * tw, 3), np.uint8)
    for i, t in enumerate(tiles):
        r, c = divmod(i, cols)
        out[r * th:(r + 1) * th, c * tw:(c + 1) * tw] = t
    return out


def _letterbox(img: np.ndarray, tw: int, th: int) -> tuple[np.ndarray, float, tuple[int, int]]:
    """Resize into a (th, tw) tile keeping the aspect; return the tile, scale and offset (x, y)."""
    h, w = img.shape[:2]
    s = min(tw / w, th / h)
    nw, nh = max(1, int(round(w * s))), max(1, int(round(h * s)))
    tile = np.zeros((th, tw, 3), np.uint8)
    ox, oy = (tw - nw) // 2, (th - nh) // 2
    tile[oy:oy + nh, ox:ox + nw] = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_AREA)
    return tile, s, (ox, oy)


def _overlay_frame(data: ReportData, cam: str, rgb: np.ndarray, t_cam: float, tw: int, th: int,
                   people: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """One camera frame resized into a (th, tw) tile with the people's meshes (person id,
    vertices (V, 3)) at its time drawn over it."""
    camera = data.rig[cam]
    h, w = rgb.shape[:2]
    s = min(tw / w, th / h)
    small = cv2.resize(rgb, (max(1, int(round(w * s))), max(1, int(round(h * s)))), interpolation=cv2.INTER_AREA)
    meshes = [(V, person_colour(pid)) for pid, V in people]
    small = draw_meshes(small, camera, s, meshes, data.body_model.np.faces)
    tile, _, _ = _letterbox(small, tw, th)
    return _label(tile, f"{cam}  t={data.clock(cam).to_ref(t_cam):.2f}s")


def _meshes_for(data: ReportData, cam: str, idx: np.ndarray, ts: np.ndarray) -> dict[int, list]:
    """{frame index: [(person id, vertices (V, 3))]} for the camera's frames ``idx`` (timestamps
    ``ts``), each person only inside their fitted span."""
    out: dict[int, list] = {int(i): [] for i in idx}
    t_ref = data.clock(cam).to_ref(ts[idx])
    for person in data.people:
        V_nv3, inside = data.meshes_at(person, t_ref)
        for k in np.flatnonzero(inside):
            out[int(idx[k])].append((person.id, V_nv3[k]))
    return out


def _png(path: Path, rgb: np.ndarray) -> Path:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 6])
    if not ok:
        raise RuntimeError(f"PNG encoding failed for {path}")
    return atomic_write_bytes(path, buf.tobytes())


def overlay_cameras(data: ReportData) -> tuple[list[str], list[str]]:
    """Cameras that can show overlays (calibrated, with a video), and notes on the others."""
    cams, notes = [], []
    for c in data.cameras:
        if c not in data.rig:
            notes.append(f"{c}: not in calibration.toml")
        elif data.video(c) is None:
            notes.append(f"{c}: video not found")
        else:
            cams.append(c)
    return cams, notes


def _fitted_span(data: ReportData) -> tuple[float, float]:
    return (min(float(p.frame_times[0]) for p in data.people), max(float(p.frame_times[-1]) for p in data.people))


def overlay_stills(data: ReportData, cam: str, out_path: Path, n: int = STILLS_PER_CAMERA,
                   width: int = STILLS_WIDTH) -> tuple[Path, list[float]] | None:
    """Evenly spaced frames of one camera inside the fitted span with the meshes drawn, ``width``
    px wide: a 2x2 grid for large landscape videos, else one row. Returns the PNG and the frames'
    reference times, or None if no frame lies in the span."""
    from mamma_kit.video.reader import VideoReader

    reader = VideoReader(data.video(cam), data.rotation(cam))
    ts = reader.timestamps
    t0, t1 = _fitted_span(data)
    t_ref = data.clock(cam).to_ref(ts)
    idx = np.flatnonzero((t_ref >= t0) & (t_ref <= t1))
    if not len(idx):
        return None
    pick = np.unique(idx[np.round(np.linspace(0, len(idx) - 1, min(n, len(idx)))).astype(int)])
    people = _meshes_for(data, cam, pick, ts)
    w, h = reader.size
    cols = 2 if (len(pick) == 4 and w > h and w > width // 2) else len(pick)
    tw = min(width // cols, w)
    th = int(round(h * tw / w))
    # a seek per frame: the stills are spread over the whole take, decoding all between them is slow
    tiles = [_overlay_frame(data, cam, rgb, t, tw, th, people[int(i)])
             for i in pick for t, rgb in [reader.frame_index(int(i))]]
    return _png(out_path, _grid(tiles, cols)), [float(data.clock(cam).to_ref(ts[i])) for i in pick]


def overlay_video(data: ReportData, cams: list[str], out_path: Path, seconds: float = VIDEO_SECONDS,
                  width: int = VIDEO_WIDTH) -> dict | None:
    """A short H.264 clip: up to four cameras side by side (2x2 for 3-4) with the meshes, on the
    fitted frames' reference times from the start of the fitted span. Returns what it holds."""
    from mamma_kit.video.reader import VideoReader
    from mamma_kit.video.writer import VideoWriter

    from mamma_kit.report.analysis import nearest_frame

    cams = cams[:VIDEO_CAMERAS]
    ft = max((p.frame_times for p in data.people), key=len)
    fps = float(1.0 / np.median(np.diff(ft))) if len(ft) > 1 else 30.0
    t_out = ft[ft <= ft[0] + seconds + 1e-9][: max(1, int(round(seconds * fps)))]
    cols = 1 if len(cams) == 1 else 2
    rows = -(-len(cams) // cols)
    readers = {c: VideoReader(data.video(c), data.rotation(c)) for c in cams}
    w0, h0 = readers[cams[0]].size
    tw = (min(width // cols, w0) // 2) * 2
    th = (int(round(h0 * tw / w0)) // 2) * 2
    frames: dict[str, dict[int, np.ndarray]] = {}
    chosen = {}
    for c in cams:
        ts = readers[c].timestamps
        j, near = nearest_frame(ts, data.clock(c).to_cam(t_out))
        chosen[c] = (j, near)
        need = np.unique(j[near])
        people = _meshes_for(data, c, need, ts)
        frames[c] = {i: _overlay_frame(data, c, rgb, t, tw, th, people[i])
                     for i, t, rgb in readers[c].read_indices(need)}
    blank = np.zeros((th, tw, 3), np.uint8)
    with VideoWriter(out_path, cols * tw, rows * th, fps=fps, crf=28, preset="medium") as wr:
        for k, t in enumerate(t_out):
            tiles = [frames[c].get(int(chosen[c][0][k]), blank) if chosen[c][1][k] else blank for c in cams]
            wr.write_frame(_grid(tiles, cols), float(t - t_out[0]))
    return {"cameras": cams, "frames": int(len(t_out)), "seconds": float(t_out[-1] - t_out[0] + 1 / fps),
            "size": [cols * tw, rows * th], "fps": fps}
