"""MediaPipe's hand landmarker (21 points per hand, trained on real hands) on the hands BlazePose found.

Each hand's region of interest comes from BlazePose's wrist, pinky and index points of that person
(rotated so the fingers point up, as the model was trained), so no palm detector is needed and a
hand keeps its person where people touch. The model file (hand_landmark_full.tflite, from the same
mediapipe 0.10.21 wheel as the BlazePose files, Apache-2.0) is checked like them (runtime.py).

>>> hl = HandLandmarker()
>>> rois = hand_rois(xy_p33, side=0)          # (P, 4) cx, cy, side, rotation of the left hands
>>> hands = hl.landmarks(rgb_hw3, rois)       # xy (P, 21, 2) image px, presence (P,)

Points (MediaPipe's order): 0 wrist; thumb 1-4 (CMC, MCP, IP, tip); index 5-8, middle 9-12,
ring 13-16, pinky 17-20 (MCP, PIP, DIP, tip).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mamma_kit.core.tracks import HAND_SURE_FLAG, N_HAND_POINTS
from mamma_kit.keypoints import blazepose as bp
from mamma_kit.keypoints.runtime import TfliteModel

HAND_LANDMARKER = "hand_landmark_full.tflite"
HAND_SIZE = 224
# BlazePose's (wrist, pinky, index) of the left and right hand
HAND_POINTS = {0: (15, 17, 19), 1: (16, 18, 20)}
# the ROI: centred this far from the wrist towards the knuckles' midpoint, its side this many wrist
# to knuckle distances (on the demo's hands, sides of 2.2 / 2.8 / 3.4 gave finger joints at 1.97 /
# 1.72 / 1.76 % of the box height where the model was sure of the hand)
CENTRE_ALONG = 0.9
SIDE_LENGTHS = 2.8
MIN_PRESENCE = HAND_SURE_FLAG  # the model's hand flag below this: no hand in the ROI
#: bones between the 21 points: each finger's chain from the wrist, and across the knuckles
HAND_SKELETON = tuple((a, a + 1) for f in range(5) for a in range(4 * f + 1, 4 * f + 4)) + \
    ((0, 1), (0, 5), (0, 17), (5, 9), (9, 13), (13, 17))


def hand_rois(xy_p33: np.ndarray, side: int) -> np.ndarray:
    """(P, 4) ROIs (cx, cy, side px, rotation) of one hand (0 left, 1 right) of P people from their
    BlazePose points (P, 33, 2) px; NaN rows where a point is missing or the hand has no extent."""
    w, p, i = (np.asarray(xy_p33, np.float64)[:, j] for j in HAND_POINTS[side])
    d = (p + i) / 2 - w  # wrist -> knuckles
    centre = w + CENTRE_ALONG * d
    # roi_from_points' side is 2 |scale point - centre| x scale: a point SIDE_LENGTHS / 2 lengths on
    rois = bp.roi_from_points(centre, centre + (SIDE_LENGTHS / 2) * d, scale=1.0)
    rois[~(np.linalg.norm(d, axis=1) > 1.0)] = np.nan
    return rois


@dataclass
class HandResult:
    xy: np.ndarray  # (N, 21, 2) image px
    z: np.ndarray  # (N, 21) relative depth, in the ROI's px
    presence: np.ndarray  # (N,) the model's hand flag in [0, 1]
    right: np.ndarray  # (N,) the model's handedness score (1: a right hand)


class HandLandmarker:
    def __init__(self, threads: int | None = None):
        self.model = TfliteModel(HAND_LANDMARKER, threads)

    def landmarks(self, image_hw3: np.ndarray, rois_n4: np.ndarray) -> HandResult:
        """21 points of the hand in each ROI (rows of NaN ROIs come back NaN with presence 0)."""
        n = len(rois_n4)
        out = HandResult(np.full((n, N_HAND_POINTS, 2), np.nan), np.full((n, N_HAND_POINTS), np.nan), np.zeros(n),
                         np.full(n, np.nan))
        ok = np.flatnonzero(np.isfinite(rois_n4).all(1))
        if not len(ok):
            return out
        crops, affines = zip(*(bp.crop_roi(image_hw3, rois_n4[j], HAND_SIZE) for j in ok))
        pts, flag, right, _ = self.model.run(np.stack(crops))
        pts = pts.reshape(len(ok), N_HAND_POINTS, 3)
        for r, (j, A) in enumerate(zip(ok, affines)):
            out.xy[j] = bp.apply_affine(bp.invert_affine(A), pts[r, :, :2] - 0.5)  # to the crop's pixel centres
            out.z[j] = pts[r, :, 2]
        out.presence[ok] = flag.reshape(-1)
        out.right[ok] = right.reshape(-1)
        return out
