"""Board specs, printing at true scale, and the synthetic board renderer's geometry."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mamma_kit.calibration.board import BoardSpec, load_board_spec, print_board, spec_from_dict
from mamma_kit.calibration.lens import undistort_exact
from mamma_kit.core.camera import Camera, distort_normalized
from mamma_kit.core.errors import UserError
from mamma_kit.synth.board import R_WORLD_FLOOR_BOARD, BoardRenderer, facing_rotation, plan_session

from conftest import make_ring_rig


def test_builtin_specs_load_and_describe():
    for name in ("charuco-a1", "charuco-a3", "charuco-a4"):
        s = load_board_spec(name)
        assert s.n_corners == (s.squares_x - 1) * (s.squares_y - 1)
        assert s.corners_b3.shape == (s.n_corners, 3)
        # corner 0 sits one square in from the top-left corner (OpenCV's layout)
        assert np.allclose(s.corners_b3[0], [s.square_m, s.square_m, 0])
        assert np.allclose(s.cv_board().getChessboardCorners(), s.corners_b3)


@pytest.mark.parametrize("bad, words", [
    ({"squares_x": 5, "squares_y": 7, "square_m": 0.04}, "missing marker_m"),
    ({"squares_x": 5, "squares_y": 7, "square_m": 0.04, "marker_m": 0.05}, "smaller than"),
    ({"squares_x": 5, "squares_y": 7, "square_m": 40, "marker_m": 30}, "metres"),
    ({"squares_x": 5, "squares_y": 7, "square_m": 0.04, "marker_m": 0.03, "dictionary": "DICT_9X9_5"}, "dictionary"),
    ({"squares_x": 5, "squares_y": 7, "square_m": 0.04, "marker_m": 0.03, "legacy": "yes"}, "true or false"),
    ({"squares_x": 5, "squares_y": 7, "square_m": 0.04, "marker_m": 0.03, "colour": 1}, "unknown field"),
    ({"squares_x": 20, "squares_y": 20, "square_m": 0.04, "marker_m": 0.03, "dictionary": "DICT_4X4_50"},
     "do not fit"),
])
def test_bad_specs_say_what_is_wrong(bad, words):
    with pytest.raises(UserError, match=words):
        spec_from_dict(bad)


def test_png_prints_at_true_scale_and_is_detected(tmp_path):
    spec = load_board_spec("charuco-a4")
    dpi = 150
    info = print_board(spec, tmp_path / "b.png", dpi=dpi)
    img = cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_GRAYSCALE)
    # page size in pixels = paper size at the dpi
    w_mm, h_mm = info["page_mm"]
    assert abs(img.shape[1] - w_mm / 25.4 * dpi) <= 1 and abs(img.shape[0] - h_mm / 25.4 * dpi) <= 1
    cc, ci, _, _ = spec.detector().detectBoard(img)
    assert ci is not None and len(ci) == spec.n_corners
    xy = np.full((spec.n_corners, 2), np.nan)
    xy[ci.ravel()] = cc.reshape(-1, 2)
    # corner spacing = the square side at the printed scale (within a pixel)
    px_per_m = dpi / 0.0254
    n = spec.squares_x - 1
    d = np.linalg.norm(xy[1:n] - xy[:n - 1], axis=1).mean()
    assert abs(d - spec.square_m * px_per_m) < 1.0
    # and the board sits where the layout says
    x0, y0 = info["board_origin_mm"]
    expect0 = (np.array([x0, y0]) / 1000 + spec.square_m) * px_per_m - 0.5
    assert np.abs(xy[0] - expect0).max() < 1.5


def test_pdf_page_is_the_paper_size(tmp_path, cli):
    r = cli("board", "charuco-a3", "--out", tmp_path / "b.pdf", "--json")
    assert r.code == 0, r
    data = (tmp_path / "b.pdf").read_bytes()
    box = re.search(rb"/MediaBox \[\s*([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)", data)
    w_pt, h_pt = float(box.group(3)), float(box.group(4))
    assert abs(w_pt - 297 / 25.4 * 72) < 0.5 and abs(h_pt - 420 / 25.4 * 72) < 0.5
    r = cli("board", "charuco-a1", "--out", tmp_path / "c.pdf", "--paper", "A4")
    assert r.code == 2 and "does not fit on A4" in r.err and "--paper A1" in r.err


@settings(max_examples=25, deadline=None)
@given(k1=st.floats(-0.18, 0.3), k2=st.floats(0.0, 0.15), p=st.floats(-0.002, 0.002), fisheye=st.booleans())
def test_undistort_inverts_the_lens_model(k1, k2, p, fisheye):
    """Within the image, where real lenses (monotonic radial distortion) are invertible."""
    if fisheye:
        cam = Camera("c", (640, 480), [[500, 0, 320], [0, 500, 240], [0, 0, 1]], [k1 / 4, k2 / 4, 0, 0], "fisheye")
    else:
        cam = Camera("c", (640, 480), [[500, 0, 320], [0, 500, 240], [0, 0, 1]], [k1, k2, p, -p, 0], "radtan")
    xy = np.random.default_rng(0).uniform([0, 0], [639, 479], (500, 2))
    xn = undistort_exact(cam, xy)
    back = cam.normalized_to_pixels(distort_normalized(xn, cam.model, cam.dist))
    assert np.abs(back - xy).max() < 1e-6


@pytest.mark.parametrize("fisheye", [False, True])
def test_rendered_corners_are_where_the_lens_model_projects_them(fisheye):
    """Inverse-mapped rendering through a strongly distorting lens: detected corners agree
    with the projection of the true corners (pooled over random poses: a rendering error
    would show as a bias, detector noise averages out)."""
    spec = load_board_spec("charuco-a3")
    if fisheye:
        cam = Camera("c", (480, 360), [[330, 0, 241.3], [0, 331, 178.9], [0, 0, 1]], [0.06, -0.02, 0.004, 0], "fisheye")
    else:
        cam = Camera("c", (480, 360), [[420, 0, 237.2], [0, 421, 182.4], [0, 0, 1]], [-0.28, 0.09, 0.001, -0.001, 0])
    ren = BoardRenderer(cam, spec, supersample=2, seed=3)
    errs = []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        R = facing_rotation(np.array([rng.normal(0, 0.25), rng.normal(0, 0.25), -1.0]), up=np.array([0, -1.0, 0]),
                             roll=rng.uniform(-np.pi, np.pi))
        # squares of at least ~25 px (smaller ones are limited by the detector, not the renderer)
        z = rng.uniform(0.55, 0.9) * cam.K[0, 0] / 420
        c = np.array([rng.uniform(-0.1, 0.1) * z, rng.uniform(-0.08, 0.08) * z, z])
        t = c - R @ spec.center_b3
        grey = cv2.cvtColor(ren.render([(R, t)], rng, noise_sigma=0.0), cv2.COLOR_RGB2GRAY)
        cc, ci, _, _ = spec.detector().detectBoard(grey)
        assert ci is not None and len(ci) >= 10
        errs.append(cc.reshape(-1, 2) - cam.project(spec.corners_b3[ci.ravel()] @ R.T + t))
    err = np.concatenate(errs)
    assert np.sqrt(np.mean(np.sum(err ** 2, 1))) < 0.12
    assert np.linalg.norm(err.mean(0)) < 0.03  # no systematic offset (e.g. a half-texel shift)


def test_session_plan_ends_with_the_floor_board_at_the_world_origin():
    rig = make_ring_rig(3, radius=2.5)
    spec = load_board_spec("charuco-a1")
    traj = plan_session(rig, spec, seed=1, duration_s=40.0, n_closeups=2)
    assert traj.kinds[-1] == "floor" and any(k == "shared" for k in traj.kinds)
    assert abs(traj.duration - 40.0) < 1e-6
    R, t = traj.pose([traj.hold_t0[-1] + 0.5])
    assert np.allclose(R[0], R_WORLD_FLOOR_BOARD) and np.allclose(t[0], 0)
    # printed face up: board -z is world +Z
    assert np.allclose(-R[0][:, 2], [0, 0, 1])
    # moves are smooth: no jumps between consecutive 10 ms samples
    ts = np.arange(0, traj.duration, 0.01)
    _, tt = traj.pose(ts)
    assert np.linalg.norm(np.diff(tt, axis=0), axis=1).max() < 0.05


def test_large_frames_are_searched_small_and_refined_at_full_resolution():
    """Frames wider than 2000 px: markers found on a reduced image, corners refined by OpenCV
    at full resolution (no accuracy lost to the reduction)."""
    from mamma_kit.calibration.detect import BoardFinder

    spec = load_board_spec("charuco-a1")
    cam = Camera("c", (2160, 1200), [[1530, 0, 1079.5], [0, 1530, 599.5], [0, 0, 1]], [0.05, -0.1, 0, 0, 0])
    ren = BoardRenderer(cam, spec, supersample=2, seed=1)
    rng = np.random.default_rng(4)
    R = facing_rotation(np.array([0.3, -0.2, -1.0]), up=np.array([0, -1.0, 0]), roll=0.2)
    t = np.array([0.2, -0.1, 2.9]) - R @ spec.center_b3
    grey = cv2.cvtColor(ren.render([(R, t)], rng, noise_sigma=2.0), cv2.COLOR_RGB2GRAY)
    finder = BoardFinder(spec, max_detect_width=2000)
    xy, n_markers = finder.detect(grey)
    ok = np.isfinite(xy[:, 0])
    assert ok.sum() == spec.n_corners and n_markers == 17
    err = xy[ok] - cam.project(spec.corners_b3[ok] @ R.T + t)
    assert np.sqrt(np.mean(np.sum(err ** 2, 1))) < 0.12


@pytest.mark.parametrize("back", ["plain", "mirror", "see-through"])
def test_board_seen_from_behind_shows_the_mirror_image_of_its_front(back):
    """From behind, a board printed on both sides (mirror) or on thin paper (see-through)
    shows its pattern mirrored, at the same 3D corners as the front; the mirrored search
    finds every corner where the lens model projects it. A plain back shows no pattern."""
    from mamma_kit.calibration.detect import BoardFinder

    spec = load_board_spec("charuco-a3")
    cam = Camera("c", (480, 360), [[420, 0, 237.2], [0, 421, 182.4], [0, 0, 1]], [-0.2, 0.05, 0.001, -0.001, 0])
    ren = BoardRenderer(cam, spec, supersample=2, seed=3, back=back)
    # the printed face (-z_b) turned away from the camera
    R = facing_rotation(np.array([0.2, -0.1, 1.0]), up=np.array([0, -1.0, 0]), roll=0.3)
    t = np.array([0.0, 0.0, 0.75]) - R @ spec.center_b3
    grey = cv2.cvtColor(ren.render([(R, t)], np.random.default_rng(0), noise_sigma=1.0), cv2.COLOR_RGB2GRAY)
    xy, n_markers, from_behind = BoardFinder(spec).detect_any_side(grey)
    if back == "plain":
        assert n_markers == 0 and not np.isfinite(xy).any()
        return
    assert from_behind and np.isfinite(xy[:, 0]).all()
    err = xy - cam.project(spec.corners_b3 @ R.T + t)
    assert np.sqrt(np.mean(np.sum(err ** 2, 1))) < 0.15, err
    # the same pose seen from the front reads the right way round
    grey = cv2.cvtColor(ren.render([(R @ np.diag([1.0, -1.0, -1.0]), t)], np.random.default_rng(0), 1.0),
                        cv2.COLOR_RGB2GRAY)
    _, _, from_behind = BoardFinder(spec).detect_any_side(grey)
    assert not from_behind


def test_session_plan_shows_a_camera_behind_the_board_only_its_back():
    """A camera named in ``behind`` never sees the front of the hand-held board; it shares
    holds with the others from behind and gets close-ups of the back."""
    from mamma_kit.synth.board import corner_visibility

    rig = make_ring_rig(4, radius=2.0, size=(480, 360), f=400.0)
    spec = load_board_spec("charuco-a3")
    traj = plan_session(rig, spec, seed=2, duration_s=40.0, n_closeups=3, floor_pose=False, behind=["cam3"])
    ts = 0.5 * (traj.hold_t0 + traj.hold_t1)
    R, t = traj.pose(ts)
    front = {c.name: np.array([corner_visibility(c, R[k], t[k], spec, 89.0) for k in range(len(ts))]) for c in rig}
    back = {c.name: np.array([corner_visibility(c, R[k], t[k], spec, 75.0, "back") for k in range(len(ts))])
            for c in rig}
    assert front["cam3"].max() == 0.0
    kinds = np.array(traj.kinds)
    assert (back["cam3"][kinds == "closeup:cam3"] > 0.5).all() and (kinds == "closeup:cam3").sum() == 3
    shared = (kinds == "shared") & (back["cam3"] > 0.8)
    assert shared.sum() >= 2
    # in those holds another camera sees the front: the views the extrinsics need
    assert all(max(front[n][k] for n in ("cam0", "cam1", "cam2")) > 0.8 for k in np.nonzero(shared)[0])
    with pytest.raises(ValueError, match="no camera cam9"):
        plan_session(rig, spec, duration_s=40.0, behind=["cam9"])


def test_double_sided_board_prints_its_mirror_image_as_a_second_page(tmp_path, cli):
    """`board --double-sided`: page 2 is page 1 mirrored left to right, so glued back to back
    (turned over like a book page) every corner of the back lies behind the same corner of
    the front; a PDF holds both pages, a PNG gets <name>-back.png beside it."""
    from mamma_kit.calibration.detect import BoardFinder

    spec = load_board_spec("charuco-a4")
    r = cli("board", "charuco-a4", "--out", tmp_path / "b.png", "--dpi", "100", "--double-sided", "--json")
    assert r.code == 0, r
    import json

    info = json.loads(r.out)
    assert info["pages"] == 2 and info["files"] == [str(tmp_path / "b.png"), str(tmp_path / "b-back.png")]
    front = cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_GRAYSCALE)
    back = cv2.imread(str(tmp_path / "b-back.png"), cv2.IMREAD_GRAYSCALE)
    assert front.shape == back.shape
    finder = BoardFinder(spec)
    xy_f, _, behind_f = finder.detect_any_side(front)
    xy_b, _, behind_b = finder.detect_any_side(back)
    assert not behind_f and behind_b  # the back reads only mirrored
    assert np.isfinite(xy_f).all() and np.isfinite(xy_b).all()
    # turned over left to right, the back's point at x mm from the page's left edge lies
    # behind the front's at (page width - x): within 0.1 mm for every corner
    px_per_mm = 100 / 25.4
    xy_b[:, 0] = info["page_mm"][0] * px_per_mm - 1 - xy_b[:, 0]
    assert np.abs(xy_b - xy_f).max() / px_per_mm < 0.1
    r = cli("board", "charuco-a4", "--out", tmp_path / "b.pdf", "--double-sided")
    assert r.code == 0, r
    data = (tmp_path / "b.pdf").read_bytes()
    assert len(re.findall(rb"/Type\s*/Page\b", data)) == 2
    assert "turn it over left to right" in r.err
    r = cli("board", "charuco-a4", "--out", tmp_path / "one.pdf")
    assert len(re.findall(rb"/Type\s*/Page\b", (tmp_path / "one.pdf").read_bytes())) == 1
