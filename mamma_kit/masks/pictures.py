"""A picture per camera: one frame with every track's mask tinted and its id written on it."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mamma_kit.core.io import atomic_path
from mamma_kit.core.tracks import MaskTracks, track_colour  # noqa: F401 - re-exported


def best_frame(mt: MaskTracks) -> int:
    """The frame showing the most tracks (the middle one among ties)."""
    n = mt.present.sum(1)
    if not len(n):
        return 0
    cand = np.flatnonzero(n == n.max())
    return int(cand[len(cand) // 2])


def draw_tracks(rgb_hw3: np.ndarray, mt: MaskTracks, t: int) -> np.ndarray:
    img = rgb_hw3.copy()
    H = img.shape[0]
    scale = max(0.35, H / 720)
    thick = max(1, int(round(2 * scale)))
    for k in np.flatnonzero(mt.present[t]):
        m = mt.mask(t, int(k))
        tid = int(mt.track_ids[k])
        col = np.array(track_colour(tid), np.float32)
        img[m] = (0.55 * img[m] + 0.45 * col).astype(np.uint8)
        cnts, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, cnts, -1, tuple(int(c) for c in col), thick)
        x1, y1, x2, _ = mt.boxes[t, k]
        org = (int(max(0, (x1 + x2) / 2 - 8 * scale)), int(max(12 * scale, y1 - 4 * scale)))
        cv2.putText(img, str(tid), org, cv2.FONT_HERSHEY_SIMPLEX, 0.8 * scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
        cv2.putText(img, str(tid), org, cv2.FONT_HERSHEY_SIMPLEX, 0.8 * scale, (255, 255, 255), thick, cv2.LINE_AA)
    label = f"{mt.camera}  frame {t}  t={mt.frame_times[t]:.3f} s  {int(mt.present[t].sum())} track(s)"
    cv2.putText(img, label, (int(6 * scale), H - int(8 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 0.5 * scale,
                (255, 255, 255), max(1, thick - 1), cv2.LINE_AA)
    return img


def write_track_picture(mt: MaskTracks, video: Path, path: Path, rotation: int | None = None) -> Path:
    from mamma_kit.video.reader import VideoReader

    t = best_frame(mt)
    _, rgb = VideoReader(video, rotation).frame_index(t)
    img = draw_tracks(rgb, mt, t)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, ".png") as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {path}")
    return path
