"""Where a view has no track of a person the other views see, and where that person should be in it.

For one camera and each of its frames, every person of the capture (identities.json) that none of
the camera's tracks shows at that instant, but that at least MIN_VIEWS other cameras' tracks do
(their keypoints at the nearest frame by the clocks): those cameras' BlazePose keypoints,
triangulated (visibility-weighted DLT), projected into this camera. A gap is kept where enough of
the projected skeleton lies in front of the camera and inside its image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.core.camera import Rig, triangulate_points
from mamma_kit.core.tracks import nearest_frames

# a person is looked for where at least this many other views see them (two rays fix a point)
MIN_VIEWS = 2
# at least this many of the 33 points triangulated, in front of the camera and inside its image
MIN_POINTS = 12
# a point in front of the camera by at least this much (m)
MIN_DEPTH = 0.2


@dataclass
class Gaps:
    """One camera's gaps: frame index, person id, the projected skeleton and how many views gave it."""

    frame_g: np.ndarray  # (G,) the camera's frame index
    person_g: np.ndarray  # (G,) person id
    xy_g332: np.ndarray  # (G, 33, 2) px, NaN where not triangulated or behind the camera
    views_g: np.ndarray  # (G,) other views whose keypoints gave it

    def __len__(self) -> int:
        return len(self.frame_g)


def persons_per_frame(person_tk: np.ndarray, present_tk: np.ndarray, persons: list[int]) -> np.ndarray:
    """(T, P) column of the track showing each person in each frame (-1: none), from the person id of
    every track per frame (identities.person_frames) and where the tracks have data."""
    T = person_tk.shape[0]
    out = np.full((T, len(persons)), -1, np.int64)
    for j, p in enumerate(persons):
        hit = (person_tk == p) & present_tk
        any_t = hit.any(1)
        out[any_t, j] = np.argmax(hit[any_t], axis=1)
    return out


def person_points(kf, col_tp: np.ndarray, block: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """Each person's keypoints in a camera: xy (T, P, 33, 2) and weight (T, P, 33) = visibility x
    presence of the track column col_tp (T, P) names (persons_per_frame; NaN / 0 where -1), read from
    the keypoints file ``kf`` (core.trackrows.TrackFile) a block of frames at a time."""
    T, P = col_tp.shape
    xy = np.full((T, P, 33, 2), np.nan, np.float32)
    w = np.zeros((T, P, 33), np.float32)
    for a in range(0, T, block):
        b = min(a + block, T)
        kt = kf.window(a, b, keys=("xy", "visibility", "presence"))
        t_i, p_i = np.nonzero(col_tp[a:b] >= 0)
        k_i = col_tp[a:b][t_i, p_i]
        xy[a + t_i, p_i] = kt.xy[t_i, k_i]
        w[a + t_i, p_i] = kt.visibility[t_i, k_i] * kt.presence[t_i, k_i]
    return xy, w


def find_gaps(cam: str, times_ref_t: np.ndarray, covered_tp: np.ndarray, others: dict, rig: Rig,
              persons: list[int]) -> Gaps:
    """The gaps of camera ``cam``.

    times_ref_t (T,): its frames on the reference clock; covered_tp (T, P): whether one of its tracks
    shows each person then. ``others``: camera -> (times_ref (T2,), each person's keypoints there
    xy (T2, P, 33, 2) (NaN where no track shows them) and weight (T2, P, 33) = visibility x presence
    (0 there): person_points).
    """
    T, P = covered_tp.shape
    names = [c for c in others if c != cam]
    C = len(names)
    xy_ctp = np.full((C, T, P, 33, 2), np.nan)
    w_ctp = np.zeros((C, T, P, 33))
    for i, c in enumerate(names):
        times2, xy2, w2 = others[c]
        f2 = nearest_frames(times_ref_t, times2)  # -1 farther than half a frame
        ok = f2 >= 0
        xy_ctp[i, ok] = xy2[f2[ok]]
        w_ctp[i, ok] = np.nan_to_num(w2[f2[ok]])
    views_tp = (w_ctp.max(-1) > 0).sum(0)
    t_g, p_g = np.nonzero(~covered_tp & (views_tp >= MIN_VIEWS))
    if not len(t_g) or C < MIN_VIEWS:
        return Gaps(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 33, 2)), np.zeros(0, np.int64))
    G = len(t_g)
    X = triangulate_points(rig.subset(names), xy_ctp[:, t_g, p_g].reshape(C, G * 33, 2),
                           w_ctp[:, t_g, p_g].reshape(C, G * 33)).reshape(G, 33, 3)
    camera = rig[cam]
    ok = np.isfinite(X).all(-1)
    depth = np.full((G, 33), -np.inf)
    depth[ok] = camera.to_camera(X[ok])[:, 2]
    front = ok & (depth > MIN_DEPTH)
    xy = np.full((G, 33, 2), np.nan)
    xy[front] = camera.project(X[front])
    W, H = camera.size
    inside = front & (xy[..., 0] >= 0) & (xy[..., 0] < W) & (xy[..., 1] >= 0) & (xy[..., 1] < H)
    keep = inside.sum(1) >= MIN_POINTS
    return Gaps(t_g[keep], np.asarray(persons)[p_g[keep]], xy[keep], views_tp[t_g[keep], p_g[keep]])
