"""A picture per camera: the tracked people's BlazePose skeletons on frames spread over the video."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mamma_kit.core.io import atomic_path
from mamma_kit.core.tracks import KeypointTracks, nearest_frames, track_colour
from mamma_kit.keypoints.blazepose import SKELETON
from mamma_kit.keypoints.hands import HAND_SKELETON, MIN_PRESENCE

PANELS = 4
# points the model thinks unlikely to be visible are drawn hollow
VISIBLE = 0.5


def draw_keypoints(rgb_hw3: np.ndarray, kt: KeypointTracks, t: int, frame: int | None = None) -> np.ndarray:
    """The people of ``kt``'s frame t drawn on the image (``frame``: the frame number to print, default t)."""
    img = rgb_hw3.copy()
    H = img.shape[0]
    s = max(0.35, H / 720)
    thick = max(1, int(round(2 * s)))
    for k in np.flatnonzero(kt.valid[t]):
        col = track_colour(int(kt.track_ids[k]))
        xy = kt.xy[t, k]
        for a, b in SKELETON:
            cv2.line(img, tuple(int(v) for v in xy[a]), tuple(int(v) for v in xy[b]), col, thick, cv2.LINE_AA)
        for p, v in zip(xy, kt.visibility[t, k]):
            cv2.circle(img, (int(p[0]), int(p[1])), max(2, thick + 1), col, -1 if v >= VISIBLE else thick,
                       cv2.LINE_AA)
        for side in np.flatnonzero(kt.hand_presence[t, k] > MIN_PRESENCE):  # the hands the hand model is sure of
            hxy = kt.hand_xy[t, k, side]
            for a, b in HAND_SKELETON:
                cv2.line(img, tuple(int(v) for v in hxy[a]), tuple(int(v) for v in hxy[b]), (255, 255, 255),
                         max(1, thick // 2), cv2.LINE_AA)
        top = xy[np.isfinite(xy[:, 1])][:, 1].min() if np.isfinite(xy).any() else 12
        org = (int(np.nanmean(xy[:, 0])), int(max(14 * s, top - 8 * s)))
        cv2.putText(img, str(int(kt.track_ids[k])), org, cv2.FONT_HERSHEY_SIMPLEX, 0.8 * s, (0, 0, 0), thick + 2)
        cv2.putText(img, str(int(kt.track_ids[k])), org, cv2.FONT_HERSHEY_SIMPLEX, 0.8 * s, (255, 255, 255), thick)
    label = f"{kt.camera}  frame {t if frame is None else frame}  t={kt.frame_times[t]:.3f} s  {int(kt.valid[t].sum())} person(s)"
    cv2.putText(img, label, (int(6 * s), H - int(8 * s)), cv2.FONT_HERSHEY_SIMPLEX, 0.5 * s, (255, 255, 255),
                max(1, thick - 1), cv2.LINE_AA)
    return img


def picture_frames(valid_tk: np.ndarray, n: int = PANELS) -> list[int]:
    """Up to n frames spread over the frames that have keypoints (valid_tk (T, K))."""
    have = np.flatnonzero(valid_tk.any(1)) if valid_tk.size else np.zeros(0, int)
    if not len(have):
        return [0] if len(valid_tk) else []
    return sorted({int(have[i]) for i in np.linspace(0, len(have) - 1, min(n, len(have))).round().astype(int)})


def write_keypoints_picture(kf, video: Path, path: Path, width: int = 1600, rotation: int | None = None) -> Path:
    """The frames side by side, scaled to ``width`` px in all; ``kf``: the camera's keypoints file
    (core.trackrows.TrackFile: only the frames drawn are read)."""
    from mamma_kit.video.reader import VideoReader

    frames = picture_frames(kf.valid_tk())
    reader = VideoReader(video, rotation)
    vid = nearest_frames(kf.frame_times[frames], reader.timestamps) if frames else np.zeros(0, int)
    t_of = {int(v): t for t, v in zip(frames, vid) if v >= 0}
    panels = [draw_keypoints(rgb, kf.window(t_of[i], t_of[i] + 1), 0, t_of[i])
              for i, _, rgb in reader.read_indices(sorted(t_of))]
    if not panels:
        panels = [np.zeros((kf.header['image_size'][1], kf.header['image_size'][0], 3), np.uint8)]
    row = np.concatenate(panels, 1)
    scale = min(1.0, width / row.shape[1])
    row = cv2.resize(row, (int(row.shape[1] * scale), int(row.shape[0] * scale)), interpolation=cv2.INTER_AREA)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, ".png") as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(row, cv2.COLOR_RGB2BGR))
    return path
