"""What one camera sees of each fitted body at one instant: a z-buffer of the bodies' vertices.

Each body's vertices are projected and splatted (a square of SPLAT_PX around each), the nearest body
wins each pixel, and each body's pixels are closed (a 5 x 5 closing) into its visible silhouette.
Splats close the open mesh when its vertices lie a few pixels apart, which holds at the working
size the stage renders at (placing.stage.WORK_SIDE: a person 150-350 px tall); a rasteriser of
the triangles would be exact but costs far more per frame than this for a mask of a few pixels'
accuracy.
"""

from __future__ import annotations

import cv2
import numpy as np

SPLAT_PX = 2  # vertex splat radius (px)
CLOSE = np.ones((5, 5), np.uint8)


def front_labels(cam, verts_bv3: list[np.ndarray], width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) index of the body nearest the camera at each pixel (-1: none) and each body's pixel
    count were it alone (B,). ``verts_bv3``: each body's world vertices (V, 3), or None for a body
    not there at this instant; ``cam`` a core.camera.Camera for an image of width x height."""
    W, H = int(width), int(height)
    depth = np.full(H * W, np.inf)
    label = np.full(H * W, -1, np.int64)
    alone = np.zeros(len(verts_bv3), np.int64)
    offs = np.arange(-SPLAT_PX, SPLAT_PX + 1)
    for b, verts in enumerate(verts_bv3):
        if verts is None:
            continue
        z = cam.to_camera(verts)[:, 2]
        uv = cam.project(verts)
        ok = np.isfinite(uv).all(1) & (z > 0)
        uv = np.clip(uv[ok], -1e6, 1e6)  # far outside the image: no int overflow
        u0, v0, z = np.round(uv[:, 0]).astype(np.int64), np.round(uv[:, 1]).astype(np.int64), z[ok]
        inside = (u0 >= -SPLAT_PX) & (u0 < W + SPLAT_PX) & (v0 >= -SPLAT_PX) & (v0 < H + SPLAT_PX)
        u0, v0, z = u0[inside], v0[inside], z[inside]
        if not len(u0):
            continue
        shape = (len(u0), len(offs), len(offs))
        u = np.broadcast_to(u0[:, None, None] + offs[None, :, None], shape).ravel()
        v = np.broadcast_to(v0[:, None, None] + offs[None, None, :], shape).ravel()
        zz = np.repeat(z, len(offs) ** 2)
        inb = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        idx, zz = v[inb] * W + u[inb], zz[inb]
        best = np.full(H * W, np.inf)
        np.minimum.at(best, idx, zz)  # this body's own depth per pixel
        alone[b] = int(np.isfinite(best).sum())
        nearer = best < depth
        depth[nearer], label[nearer] = best[nearer], b
    return label.reshape(H, W), alone


def visible_silhouette(label_hw: np.ndarray, b: int) -> np.ndarray:
    """(H, W) bool: body ``b``'s pixels of a front_labels map, closed."""
    return cv2.morphologyEx((label_hw == b).astype(np.uint8), cv2.MORPH_CLOSE, CLOSE).astype(bool)
