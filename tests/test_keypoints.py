"""BlazePose on LiteRT: our pre/post-processing geometry, the shipped model files' checks, and the
models on real footage (shared/real, beside the repository)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from mamma_kit.core.errors import UserError
from mamma_kit.keypoints import blazepose as bp
from mamma_kit.keypoints import runtime

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "real" / "pose2sim-multiperson"


def real_video(cam: str) -> Path:
    p = REAL / "videos" / f"{cam}.mp4"
    if not p.is_file():
        pytest.skip(f"{p} not present (CI has shared/ beside the repo)")
    return p


def test_anchor_grid_matches_the_detectors_outputs():
    a = bp.ssd_anchors()
    assert a.shape == (2254, 2)  # the detector's anchor axis
    np.testing.assert_allclose(a[0], [0.5 / 28, 0.5 / 28])
    np.testing.assert_allclose(a[1], a[0])  # two anchors per cell at stride 8
    np.testing.assert_allclose(a[-1], [6.5 / 7, 6.5 / 7])
    assert len(np.unique(a[-294:], axis=0)) == 49  # the three stride-32 layers share one 7x7 grid


@pytest.mark.parametrize("rot", [0.0, 0.7, -2.5, np.pi / 2])
def test_roi_affine_maps_centre_and_up_direction(rot):
    roi = np.array([400.0, 300.0, 200.0, rot])
    A = bp.roi_affine(roi)
    # the ROI's centre lands on the input's centre (pixel-centre coordinates)
    np.testing.assert_allclose(bp.apply_affine(A, roi[None, :2])[0], [127.5, 127.5], atol=1e-9)
    # the image direction Rot(rot) @ (0, -1) is the input's up, at 256 / side px per px
    c, s = np.cos(rot), np.sin(rot)
    up_img = np.array([s, -c])
    q = bp.apply_affine(A, (roi[:2] + 50 * up_img)[None])[0]
    np.testing.assert_allclose(q, [127.5, 127.5 - 50 * 256 / 200], atol=1e-9)
    # and the inverse brings input pixels back
    inv = bp.invert_affine(A)
    np.testing.assert_allclose(bp.apply_affine(inv, q[None])[0], roi[:2] + 50 * up_img, atol=1e-9)


def test_roi_from_points_upright_and_lying_people():
    hips = np.array([[100.0, 200.0], [100.0, 200.0]])
    scale = np.array([[100.0, 100.0], [200.0, 200.0]])  # head up; head to the right
    roi = bp.roi_from_points(hips, scale)
    np.testing.assert_allclose(roi[:, 3], [0.0, np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(roi[:, 2], 2 * 100 * bp.ROI_SCALE)


def test_letterbox_keeps_aspect_and_maps_corners():
    img = np.zeros((1920, 1080, 3), np.uint8)
    x, A = bp.letterbox(img)
    assert x.shape == (224, 224, 3) and x.min() >= -1 and x.max() <= 1
    s = 224 / 1920
    # the image's outer edges land on the padded input's edges (continuous coordinates)
    top_left_edge = bp.apply_affine(A, np.array([[-0.5, -0.5]]))[0] + 0.5
    np.testing.assert_allclose(top_left_edge, [(224 - 1080 * s) / 2, 0.0], atol=1e-9)


def test_weighted_nms_merges_a_cluster_and_keeps_apart_boxes():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [50, 50, 60, 60]], float)
    kps = np.zeros((3, 4, 2))
    kps[1] += 1.0
    scores = np.array([0.9, 0.6, 0.8])
    b, k, s = bp.weighted_nms(boxes, kps, scores)
    assert len(s) == 2 and s[0] == 0.9
    np.testing.assert_allclose(b[0], [0.6 / 1.5, 0, 10 + 0.6 / 1.5, 10])
    np.testing.assert_allclose(k[0], 0.6 / 1.5)


def test_heatmap_refinement_moves_to_the_peak():
    heat = np.full((1, 64, 64, 1), -20.0)
    heat[0, 30, 40, 0] = 20.0  # one confident cell: its centre is (40.5, 30.5) in heatmap coordinates
    xy = np.array([[[41.5 * 4 - 0.5, 29.0 * 4 - 0.5]]])  # within the 7x7 window
    out = bp.refine_with_heatmap(xy, heat)
    np.testing.assert_allclose(out[0, 0], [40.5 * 4 - 0.5, 30.5 * 4 - 0.5], atol=1e-6)
    weak = bp.refine_with_heatmap(xy, np.full((1, 64, 64, 1), -20.0))
    np.testing.assert_allclose(weak, xy)  # below the confidence to refine: unchanged


def test_missing_or_altered_model_file_is_refused(tmp_path, monkeypatch):
    monkeypatch.setenv(runtime.MODELS_ENV, str(tmp_path))
    with pytest.raises(UserError, match="missing"):
        runtime.model_path(runtime.DETECTOR)
    shutil.copy(runtime.MODELS_DIR / runtime.DETECTOR, tmp_path / runtime.DETECTOR)
    assert runtime.model_path(runtime.DETECTOR) == tmp_path / runtime.DETECTOR
    data = bytearray((tmp_path / runtime.DETECTOR).read_bytes())
    data[1000] ^= 0xFF
    (tmp_path / runtime.LANDMARKER).write_bytes(bytes(data))
    with pytest.raises(UserError, match="altered or corrupt"):
        runtime.model_path(runtime.LANDMARKER)


def test_shipped_files_match_their_sums_and_carry_the_notice():
    for name, digest in runtime.expected_sums().items():
        assert runtime.model_path(name).is_file()
    notice = (runtime.MODELS_DIR / "NOTICE").read_text()
    assert "Apache License" in notice and (runtime.MODELS_DIR / "LICENSE-mediapipe.txt").is_file()


def test_real_frame_two_people_found_and_points_inside_their_segmentation():
    from mamma_kit.keypoints.estimator import PoseEstimator
    from mamma_kit.video import VideoReader

    _, img = VideoReader(real_video("cam02")).frame_index(50)
    est = PoseEstimator()
    dets = est.detect(img, min_score=0.3)
    res = est.landmarks(img, est.rois_from_detections(dets), segmentation=True)
    people = res.score >= 0.5
    assert people.sum() >= 2
    for n in np.flatnonzero(people):
        prob, (x0, y0) = res.segmentation[n]
        seg = prob > 0.5
        vis = res.visibility[n] > 0.8
        ij = np.round(res.xy[n, vis]).astype(int) - [x0, y0]
        inside = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < seg.shape[1]) & (ij[:, 1] < seg.shape[0])
        hit = np.zeros(len(ij), bool)
        hit[inside] = seg[ij[inside, 1], ij[inside, 0]]
        assert hit.mean() >= 0.8, f"person {n}: {hit.mean():.2f} of visible points on its own mask"


def test_detector_batch_gives_each_input_its_own_outputs():
    """The detector's graph folds a batch into its anchor axis grid by grid: unfolded, a batch of
    three gives exactly what three single calls give."""
    from mamma_kit.keypoints.runtime import TfliteModel

    m = TfliteModel(runtime.DETECTOR)
    x = np.random.default_rng(0).uniform(-1, 1, (3, 224, 224, 3)).astype(np.float32)
    singles = [[bp.unfold_detector_batch(y, 1)[0] for y in m.run(x[i:i + 1])] for i in range(3)]
    raw, logits = (bp.unfold_detector_batch(y, 3) for y in m.run(x))
    for i in range(3):
        np.testing.assert_allclose(raw[i], singles[i][0], atol=1e-4)
        np.testing.assert_allclose(logits[i], singles[i][1], atol=1e-4)
