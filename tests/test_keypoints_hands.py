"""MediaPipe's hand landmarker on BlazePose's hands (keypoints/hands.py): the ROI, and real hands."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mamma_kit.keypoints import blazepose as bp
from mamma_kit.keypoints.hands import HAND_SIZE, MIN_PRESENCE, SIDE_LENGTHS, HandLandmarker, hand_rois

REAL = Path(__file__).resolve().parents[2] / "shared" / "real" / "pose2sim-multiperson"


def _points(wrist, pinky, index):
    """One person's BlazePose points with only the left hand's wrist, pinky and index."""
    xy = np.full((1, 33, 2), np.nan)
    xy[0, 15], xy[0, 17], xy[0, 19] = wrist, pinky, index
    return xy


@pytest.mark.parametrize("direction", [(0, -1), (1, 0), (-0.6, 0.8)])
def test_roi_puts_the_fingers_up_at_the_models_scale(direction):
    u = np.array(direction, float) / np.linalg.norm(direction)
    n = np.array([-u[1], u[0]])
    wrist = np.array([300.0, 200.0])
    knuckles = wrist + 20 * u
    roi = hand_rois(_points(wrist, knuckles - 6 * n, knuckles + 6 * n), 0)[0]
    assert roi[2] == pytest.approx(SIDE_LENGTHS * 20)
    A = bp.roi_affine(roi, HAND_SIZE)
    w_in, k_in = bp.apply_affine(A, np.stack([wrist, knuckles]))
    assert k_in[0] == pytest.approx(w_in[0], abs=1e-6) and k_in[1] < w_in[1]  # wrist below, knuckles above
    assert w_in[1] - k_in[1] == pytest.approx(HAND_SIZE / SIDE_LENGTHS)
    assert 0 < w_in[1] < HAND_SIZE  # the wrist stays inside the crop


def test_missing_points_give_no_roi_and_no_hand():
    xy = _points([300, 200], [290, 180], [310, 180])
    xy[0, 19] = np.nan
    rois = hand_rois(xy, 0)
    assert np.isnan(rois).all()
    assert np.isnan(hand_rois(_points([300, 200], [300, 200], [300, 200]), 0)).all()  # no extent
    res = HandLandmarker().landmarks(np.zeros((400, 600, 3), np.uint8), rois)
    assert np.isnan(res.xy).all() and res.presence[0] == 0


def test_real_hands_are_found_where_blazepose_puts_them():
    if not (REAL / "videos" / "cam01.mp4").is_file():
        pytest.skip(f"{REAL} not present (CI has shared/ beside the repo)")
    from mamma_kit.keypoints.estimator import PoseEstimator
    from mamma_kit.video import VideoReader

    r = VideoReader(REAL / "videos" / "cam02.mp4")
    _, _, img = next(iter(r.read_indices([10])))
    est, hl = PoseEstimator(), HandLandmarker()
    dets = est.detect(img)
    res = est.landmarks(img, est.rois_from_detections(dets))
    sure = 0
    for side in (0, 1):
        rois = hand_rois(res.xy, side)
        hands = hl.landmarks(img, rois)
        for j in np.flatnonzero(hands.presence > MIN_PRESENCE):
            sure += 1
            wrist = res.xy[j, 15 + side]
            spread = np.linalg.norm(hands.xy[j] - hands.xy[j, 0], axis=1).max()
            assert np.linalg.norm(hands.xy[j, 0] - wrist) < 0.5 * rois[j, 2]  # its wrist is BlazePose's
            assert 0.15 * rois[j, 2] < spread < rois[j, 2]  # a hand's extent, inside the ROI
    assert sure >= 1
