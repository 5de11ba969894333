"""Touching people's masks re-split by their skeletons (BlazePose's 33 points per person).

A mask tracker that splits a blob by prediction and colour (masks/tracker.py) gets the place where
two people touch wrong most often at their hands: two dancers holding hands are one blob there, two
arms of the same colour, and the cut falls anywhere along the joined arms. A keypoint model that
sees the whole body knows where each person's wrist and fingers are. So, per frame, the pixels of
touching masks near that contact are given again to the person whose body (drawn as thick limbs
from its points) is nearer: a pixel changes hands only where the other's body is clearly nearer
than its own (``margin``), and only within ``reach`` of a body, so hair, loose clothes and
unexplained parts keep the tracker's answer.

``split_touching`` is the only entry point. The keypoints stage calls it with each frame's first
points and runs BlazePose again on the masks it changed, so a person's points come from its own
pixels, not its partner's arm. masks/<cam>.npz stays the tracker's own output. (The landmark
networks read the tracker's masks: re-split there too, the demo's landmarks moved by 0.03 % of the
box height and the person-contact AUC fell from 0.848 to 0.831, the contact head reading where
the masks meet.)
"""

from __future__ import annotations

import cv2
import numpy as np

# BlazePose indices: the limbs drawn for a person, with their half-thickness as a share of the
# person's size (its shoulder-to-ankle length); thin where the arm is thin, so a hand is drawn as
# the hand, not as a blob that swallows the other person's fingers
LIMBS = (
    ((11, 13), 0.045), ((12, 14), 0.045), ((13, 15), 0.035), ((14, 16), 0.035),  # upper arms, forearms
    ((15, 17), 0.025), ((15, 19), 0.025), ((15, 21), 0.02), ((17, 19), 0.025),  # left hand
    ((16, 18), 0.025), ((16, 20), 0.025), ((16, 22), 0.02), ((18, 20), 0.025),  # right hand
    ((23, 25), 0.06), ((24, 26), 0.06), ((25, 27), 0.045), ((26, 28), 0.045),  # thighs, shins
    ((27, 29), 0.03), ((28, 30), 0.03), ((29, 31), 0.03), ((30, 32), 0.03), ((27, 31), 0.03), ((28, 32), 0.03),
    ((0, 7), 0.05), ((0, 8), 0.05), ((7, 8), 0.05),  # head
)
TORSO = (11, 12, 24, 23)  # shoulders and hips: the torso polygon, filled
# a point drawn only when BlazePose is this sure of it (its visibility): a limb it guesses behind
# the other person must not claim the pixels in front
MIN_VISIBILITY = 0.5
# where the split is redone: within this share of the person's size of where two masks meet
CONTACT_SHARE = 0.12
# a pixel goes to the other person only if its body is nearer than its own by this share of the size
MARGIN_SHARE = 0.02
# ...and the other's body is within this share of the size (further away nobody explains the pixel)
REACH_SHARE = 0.05


def person_size(points_p5: np.ndarray) -> float | None:
    """Shoulder-to-ankle length (px) of one skeleton: the mean of both sides' shoulder-hip-knee-ankle
    chains, each counted where its points are sure; None without one."""
    out = []
    for chain in ((11, 23, 25, 27), (12, 24, 26, 28)):
        xy = points_p5[list(chain), :2]
        if np.all(points_p5[list(chain), 3] >= MIN_VISIBILITY) and np.all(np.isfinite(xy)):
            out.append(float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()))
    if not out:  # legs hidden: the torso is about 0.4 of it
        xy = points_p5[list(TORSO), :2]
        if np.all(points_p5[list(TORSO), 3] >= MIN_VISIBILITY) and np.all(np.isfinite(xy)):
            out.append(2.5 * 0.5 * (np.linalg.norm(xy[0] - xy[3]) + np.linalg.norm(xy[1] - xy[2])))
    return float(np.mean(out)) if out else None


def body_distance(points_p5: np.ndarray, size: float, shape_hw: tuple[int, int], origin_xy: tuple[int, int]
                  ) -> np.ndarray:
    """(H, W) float32 distance (px) of every pixel of a window from the person's drawn body (0 inside);
    the window is ``shape_hw`` at ``origin_xy`` of the image. Large where nothing is drawn."""
    h, w = shape_hw
    body = np.zeros((h, w), np.uint8)
    sure = (points_p5[:, 3] >= MIN_VISIBILITY) & np.all(np.isfinite(points_p5[:, :2]), 1)
    xy = points_p5[:, :2] - np.asarray(origin_xy, np.float64)
    shift = 4  # sub-pixel line ends
    for (a, b), r in LIMBS:
        if sure[a] and sure[b]:
            pa, pb = (np.round(xy[[a, b]] * (1 << shift))).astype(np.int64)
            cv2.line(body, tuple(int(v) for v in pa), tuple(int(v) for v in pb), 1, max(1, int(round(2 * r * size))),
                     cv2.LINE_8, shift)
    if np.all(sure[list(TORSO)]):
        poly = np.round(xy[list(TORSO)] * (1 << shift)).astype(np.int32)
        cv2.fillPoly(body, [poly], 1, cv2.LINE_8, shift)
    if not body.any():
        return np.full((h, w), np.inf, np.float32)
    return cv2.distanceTransform(1 - body, cv2.DIST_L2, 3)


def split_touching(masks: dict[int, np.ndarray | None], points: dict[int, np.ndarray | None]
                   ) -> dict[int, np.ndarray | None]:
    """Each person's mask (bool (H, W) per track id) after re-splitting where it touches another's.

    ``points``: each track's BlazePose points (33, 5: x, y, z, visibility, presence), or None.
    Masks without a skeleton (or alone in the frame) come back as they were; a changed mask is a
    new array (the inputs are not edited)."""
    keys = [k for k, m in masks.items() if m is not None and m.any()]
    sizes = {k: person_size(points[k]) if points.get(k) is not None else None for k in keys}
    keys = [k for k in keys if sizes[k]]
    if len(keys) < 2:
        return masks
    out = dict(masks)
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            ma, mb = out[a], out[b]
            size = min(sizes[a], sizes[b])
            r = max(1, int(round(CONTACT_SHARE * size)))
            k_r = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
            # where the two meet (each grown by a pixel), then the window around it
            meet = (cv2.dilate(ma.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0) & mb
            if not meet.any():
                continue
            ys, xs = np.nonzero(meet)
            H, W = ma.shape
            x0, y0 = max(0, xs.min() - 2 * r), max(0, ys.min() - 2 * r)
            x1, y1 = min(W, xs.max() + 2 * r + 1), min(H, ys.max() + 2 * r + 1)
            win = (slice(y0, y1), slice(x0, x1))
            near = cv2.dilate(meet[win].astype(np.uint8), k_r) > 0
            da = body_distance(points[a], sizes[a], (y1 - y0, x1 - x0), (x0, y0))
            db = body_distance(points[b], sizes[b], (y1 - y0, x1 - x0), (x0, y0))
            wa, wb = ma[win], mb[win]
            margin, reach = MARGIN_SHARE * size, REACH_SHARE * size
            to_b = near & wa & (db + margin < da) & (db <= reach)
            to_a = near & wb & (da + margin < db) & (da <= reach)
            if not (to_b.any() or to_a.any()):
                continue
            na, nb = ma.copy(), mb.copy()
            na[win] = (wa & ~to_b) | to_a
            nb[win] = (wb & ~to_a) | to_b
            out[a], out[b] = na, nb
    return out
