"""`mamma-kit calibrate` end to end on rendered board videos, and its failure messages.

The accuracy test renders a small, fast session (3 cameras at 480x360 on a 1.8 m ring,
unsynchronised clocks, 42 s at 5 fps, H.264, noise, motion blur, hand tremor) and checks
the calibration against the ground truth with tolerances for that setting. The issue's
figures (focal < 0.2 %, principal point < 1 px, rotation < 0.05 deg, centre < 2 mm at a
4.5 m ring) are for iPhone-like resolution and a full session: see
benchmarks/calib_vs_aniposelib.py and the README.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mamma_kit.calibration.board import BoardSpec, load_board_spec
from mamma_kit.core.calibfile import read_calibration, write_calibration
from mamma_kit.core.camera import Camera, Rig, rodrigues
from mamma_kit.core.clock import ClockModel
from mamma_kit.core.io import write_toml
from mamma_kit.evaluation.calibration import align_rig, compare
from mamma_kit.synth.board import BoardTrajectory, plan_session, render_board_session

TRUE_OFFSETS = {"cam0": 0.0, "cam1": 0.43, "cam2": -1.37}


def look_at(C, target, roll=0.0):
    z = np.asarray(target, float) - C
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        x = np.array([1.0, 0, 0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    if roll:
        c, s = np.cos(roll), np.sin(roll)
        R = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ R
    return R


def ring(n=3, radius=1.8, height=1.4, target_z=0.5, size=(480, 360), f=430.0, seed=0) -> Rig:
    """Cameras on a ring looking slightly down at the volume (the floor board in view);
    cam1 is a phone held in portrait (rotated 90 degrees about its axis)."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.3
        C = np.array([radius * np.cos(a), radius * np.sin(a), height])
        w, h = size
        roll = 0.0
        if i == 1:
            w, h, roll = h, w, np.pi / 2
        R = look_at(C, [0, 0, target_z], roll)
        fi = f * (1 + 0.01 * rng.standard_normal())
        K = np.array([[fi, 0, w / 2 - 0.5 + rng.uniform(-6, 6)], [0, fi * 1.001, h / 2 - 0.5 + rng.uniform(-6, 6)],
                      [0, 0, 1]])
        cams.append(Camera(f"cam{i}", (w, h), K, [-0.12, 0.05, 0.0005, -0.0003, 0.0], "radtan", R, -R @ C))
    return Rig(cams)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A rendered workspace: board videos, capture.toml, gt/calibration.toml."""
    ws = tmp_path_factory.mktemp("calib_ws")
    rig = ring()
    spec = load_board_spec("charuco-a1")
    clocks = {n: ClockModel(offset=o, rate=20e-6 if n == "cam2" else 0.0) for n, o in TRUE_OFFSETS.items()}
    traj = plan_session(rig, spec, seed=7, duration_s=42.0, n_closeups=3, hold_s=(1.2, 2.0))
    info = render_board_session(ws / "board", rig, spec, seed=7, duration_s=42.0, fps=5.0, clocks=clocks,
                                trajectory=traj, supersample=2, progress=False)
    write_toml(ws / "board" / "board.toml", spec.to_dict())
    write_toml(ws / "capture.toml", {
        "capture": {"name": "calib-test"}, "board": {"spec": "board/board.toml"},
        "cameras": {n: {"video": f"board/{n}.mp4", "board_video": f"board/{n}.mp4"} for n in rig.names}})
    (ws / "gt").mkdir()
    write_calibration(ws / "gt" / "calibration.toml", rig)
    return {"ws": ws, "rig": rig, "info": info}


@pytest.fixture(scope="module")
def calibrated(session, tmp_path_factory):
    from mamma_kit.cli.app import main

    import contextlib
    import io
    import sys

    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(["calibrate", str(session["ws"]), "--json", "--quiet"])
        except SystemExit as e:
            code = e.code or 0
    assert code == 0, err.getvalue()[-2000:]
    return json.loads(out.getvalue())


def test_json_reports_per_camera_and_bundle_adjusted_rms(calibrated, session):
    assert set(calibrated["cameras"]) == {"cam0", "cam1", "cam2"}
    for d in calibrated["cameras"].values():
        assert 0 < d["rms_px"] < 0.3
    assert 0 < calibrated["rms_px"] < 0.3
    assert calibrated["world"]["source"] == "floor"
    assert calibrated["events"]["shared"] >= 4


def test_calibration_matches_ground_truth(calibrated, session, cli):
    """Tolerances for this small low-resolution setting (480x360, f = 430 px, 1.8 m ring,
    3 close-up holds per camera): focal 0.5 %, principal point 4 px, rotation 0.6 deg,
    centre 20 mm with the world pinned by the floor board (no alignment)."""
    r = cli("eval", session["ws"], "--json")
    assert r.code == 0, r
    ev = json.loads(r.out)["calibration"]
    assert ev["aligned"] == "floor"  # the floor board pinned the world frame: only its yaw and place are aligned
    w = ev["worst"]
    assert w["focal_pct"] < 0.5, ev
    assert w["principal_point_px"] < 4.0, ev
    assert w["rotation_deg"] < 0.6, ev
    assert w["center_mm"] < 20.0, ev
    assert w["reprojection_px_mean"] < 2.5, ev


def test_board_clock_offsets_are_recovered(session):
    _, diag = read_calibration(session["ws"] / "calibration.toml")
    for n, o in TRUE_OFFSETS.items():
        assert abs(diag["cameras"][n]["board_clock_offset_s"] - o) < 0.15


def test_diagnostics_and_figures(session, calibrated):
    _, diag = read_calibration(session["ws"] / "calibration.toml")
    rig_d = diag["rig"]
    assert rig_d["model"] == "radtan" and rig_d["board"]["dictionary"] == "DICT_4X4_50"
    for n in ("cam0", "cam1", "cam2"):
        d = diag["cameras"][n]
        assert len(d["per_view_rms_px"]) == d["views"]
        assert {"fx", "fy", "cx", "cy", "k1"} <= set(d["intrinsics_std"])
        assert d["intrinsics_std"]["fx"] > 0 and d["bundle_std"]["fx"] > 0
        assert d["cross_validation_px"]["median_px"] < 2.0
    # the portrait camera keeps its stored (portrait) frame size
    assert diag["cameras"]["cam1"]["size"] == [360, 480]
    figs = calibrated["figures"]
    names = {Path(f).name for f in figs}
    assert names == {"camera_cam0.png", "camera_cam1.png", "camera_cam2.png", "connectivity.png", "rig.png"}
    for f in figs:
        assert Path(f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and Path(f).stat().st_size > 20_000


def test_unchanged_workspace_is_not_recalibrated(session, calibrated, cli):
    r = cli("calibrate", session["ws"], "--json")
    assert r.code == 0 and json.loads(r.out)["skipped"] is True


@pytest.mark.slow
def test_rotated_board_videos_give_the_same_calibration(session, calibrated, tmp_path, cli):
    """Issue 41: the same board videos as phones store them (each camera's picture stored turned
    back with its display rotation, HEVC Main10 .mov, AAC; cam0 90, cam1 270, cam2 180 degrees)
    calibrate to the unrotated ones' calibration, in the same displayed frames, within the noise
    of a second encoding."""
    from mamma_kit.video.orientation import Orientation
    from mamma_kit.video.phone import phone_copy

    ws = tmp_path / "ws"
    (ws / "board").mkdir(parents=True)
    turns = {"cam0": 90, "cam1": 270, "cam2": 180}
    for n, cw in turns.items():
        phone_copy(session["ws"] / "board" / f"{n}.mp4", ws / "board" / f"{n}.mov", orientation=Orientation(cw),
                   crf=12, preset="ultrafast")
    write_toml(ws / "board" / "board.toml", load_board_spec("charuco-a1").to_dict())
    write_toml(ws / "capture.toml", {
        "capture": {"name": "calib-rotated"}, "board": {"spec": "board/board.toml"},
        "cameras": {n: {"video": f"board/{n}.mov", "board_video": f"board/{n}.mov"} for n in turns}})
    r = cli("calibrate", ws, "--json", "--quiet", "--no-figures")
    assert r.code == 0, r
    rot, _ = read_calibration(ws / "calibration.toml")
    ref, _ = read_calibration(session["ws"] / "calibration.toml")
    for n in turns:
        assert rot[n].size == ref[n].size, n
    # one run: 0.21 deg, 5.5 mm, focal 0.20 %, principal point 1.3 px between the two (half the
    # tolerances the unrotated calibration meets against the truth, test above)
    w = compare(rot, ref, align="none")["worst"]
    assert w["rotation_deg"] < 0.3 and w["center_mm"] < 10.0 and w["focal_pct"] < 0.3, w
    assert w["principal_point_px"] < 2.0, w
    w = compare(rot, session["rig"], align="floor")["worst"]
    assert w["focal_pct"] < 0.5 and w["principal_point_px"] < 4.0 and w["rotation_deg"] < 0.6, w


# ---- failures: one line, exit code 2, and what to do ----------------------------------
def _one_camera(tmp: Path, printed: BoardSpec, n_closeups=3, duration=3.0, fps=3.0, name="cam0",
                trajectory=None) -> Path:
    C = np.array([0.0, -2.0, 1.2])
    R = look_at(C, [0, 0, 1.0])
    cam = Camera(name, (400, 300), [[360, 0, 199.5], [0, 360, 149.5], [0, 0, 1]], [-0.05, 0, 0, 0, 0], "radtan",
                 R, -R @ C)
    render_board_session(tmp, Rig([cam]), printed, seed=3, duration_s=duration, fps=fps, n_closeups=n_closeups,
                         floor_pose=False, supersample=2, progress=False, trajectory=trajectory,
                         closeup_fill=(0.55, 0.8))
    return tmp / f"{name}.mp4"


SPEC = BoardSpec(5, 6, 0.06, 0.045, "DICT_4X4_50", name="test-board")  # even rows: legacy matters


@pytest.mark.parametrize("printed, expect", [
    (SPEC.with_(dictionary="DICT_5X5_100"), ['another dictionary', 'dictionary = "DICT_5X5_']),
    (SPEC.with_(legacy=True), ["the legacy layout", "legacy = true"]),
    (SPEC.with_(inverted=True), ["inverted colours", "inverted = true"]),
    (SPEC.with_(squares_x=6, squares_y=5), ["swapped rows/columns", "squares_x = 6, squares_y = 5"]),
])
def test_wrong_board_spec_names_the_variant_that_matches(tmp_path, cli, printed, expect):
    video = _one_camera(tmp_path / "v", printed)
    write_toml(tmp_path / "spec.toml", SPEC.to_dict())
    r = cli("calibrate", video, "--board", tmp_path / "spec.toml", "--out", tmp_path / "c.toml", "--quiet")
    assert r.code == 2, r
    line = r.err.strip()
    assert line.count("\n") == 0 and "Traceback" not in line
    assert "camera cam0: no ChArUco board found" in line
    for e in expect:
        assert e in line, line
    assert not (tmp_path / "c.toml").exists()


def test_camera_that_never_shares_a_view_is_named(tmp_path, cli):
    """Two cameras back to back: each sees only its own close-ups."""
    cams = []
    for name, C, target in (("front", [0.0, -1.0, 1.2], [0, -4.0, 1.0]), ("back", [0.0, 1.0, 1.2], [0, 4.0, 1.0])):
        C = np.array(C)
        R = look_at(C, target)
        cams.append(Camera(name, (400, 300), [[360, 0, 199.5], [0, 360, 149.5], [0, 0, 1]], [0, 0, 0, 0, 0], "radtan",
                           R, -R @ C))
    render_board_session(tmp_path, Rig(cams), SPEC, seed=5, duration_s=12.0, fps=3.0, n_closeups=6, floor_pose=False,
                         supersample=2, progress=False, closeup_fill=(0.5, 0.8))
    write_toml(tmp_path / "spec.toml", SPEC.to_dict())
    r = cli("calibrate", tmp_path / "front.mp4", tmp_path / "back.mp4", "--board", tmp_path / "spec.toml",
            "--out", tmp_path / "c.toml", "--no-figures")
    assert r.code == 2, r
    line = r.err.strip()
    assert "not connected" in line and "back" in line and "front" in line
    assert "both see it" in line


def test_too_few_views(tmp_path, cli):
    C = np.array([0.0, -2.0, 1.2])
    Rc = look_at(C, [0, 0, 1.0])
    centre = Rc.T @ np.array([0.0, 0.0, 0.8]) + C
    R_wb = Rc.T @ rodrigues(np.array([0.5, 0.3, 0.0]))  # tilted, in view, but only three frames
    traj = BoardTrajectory(SPEC, R_wb[None], centre[None], np.array([0.0]), np.array([1.0]), ["closeup:cam0"])
    video = _one_camera(tmp_path, SPEC, duration=1.0, fps=3.0, trajectory=traj)
    write_toml(tmp_path / "spec.toml", SPEC.to_dict())
    r = cli("calibrate", video, "--board", tmp_path / "spec.toml", "--out", tmp_path / "c.toml")
    assert r.code == 2 and "too few views" in r.err and "cam0" in r.err, r


def test_face_on_views_are_degenerate(tmp_path, cli):
    """Board only ever square to the camera: focal length and distance cannot be separated."""
    C = np.array([0.0, -2.0, 1.2])
    Rc = look_at(C, [0, 0, 1.0])
    # board-to-world rotations whose printed face looks straight back at the camera
    R_wb = Rc.T @ np.diag([1.0, 1.0, 1.0])  # board axes = camera axes: face-on, upright
    pts, rots = [], []
    for dx, dy, d in ((-0.15, -0.1, 0.8), (0.15, -0.1, 0.9), (0.0, 0.1, 0.75), (-0.12, 0.12, 0.85),
                      (0.14, 0.1, 0.8), (0.0, 0.0, 0.95)):
        centre_c = np.array([dx, dy, d])
        pts.append(Rc.T @ (centre_c - (-Rc @ C)))
        rots.append(R_wb)
    n = len(pts)
    traj = BoardTrajectory(SPEC, np.stack(rots), np.stack(pts), np.arange(n) * 1.0 + 0.2, np.arange(n) * 1.0 + 0.7,
                           ["closeup:cam0"] * n)
    video = _one_camera(tmp_path, SPEC, duration=float(n), fps=4.0, trajectory=traj)
    write_toml(tmp_path / "spec.toml", SPEC.to_dict())
    r = cli("calibrate", video, "--board", tmp_path / "spec.toml", "--out", tmp_path / "c.toml")
    assert r.code == 2 and "degenerate views" in r.err and "tilt" in r.err, r


def test_missing_board_spec_and_videos(tmp_path, cli):
    r = cli("calibrate", tmp_path / "nope.mp4", "--board", "charuco-a1")
    assert r.code == 2 and "not found" in r.err
    r = cli("calibrate", tmp_path / "a.mp4")
    assert r.code == 2 and "--board" in r.err


# ---- geometry helpers -------------------------------------------------------------------
@settings(max_examples=30, deadline=None)
@given(rv=st.lists(st.floats(-3, 3), min_size=3, max_size=3), t=st.lists(st.floats(-5, 5), min_size=3, max_size=3),
       s=st.floats(0.2, 5.0))
def test_similarity_alignment_undoes_any_similarity(rv, t, s):
    gt = ring(4, radius=4.5, height=1.6)
    moved = gt.transformed(rodrigues(np.array(rv)), np.array(t), s)
    back, info = align_rig(moved, gt)
    assert abs(info["scale"] - 1 / s) < 1e-6 * max(1, 1 / s)
    res = compare(moved, gt, align="similarity")
    assert res["worst"]["center_mm"] < 1e-3 and res["worst"]["rotation_deg"] < 1e-5


@settings(max_examples=30, deadline=None)
@given(yaw=st.floats(-3.1, 3.1), shift=st.lists(st.floats(-5, 5), min_size=2, max_size=2),
       tilt=st.floats(0.005, 0.05))
def test_floor_alignment_undoes_the_board_place_but_not_a_tilt(yaw, shift, tilt):
    """Where a floor board lay and how it was turned no calibration knows: after the floor
    alignment a rig turned about Z and moved along the floor has no error left, while a tilt of
    its up axis stays in the errors, and every reprojection figure is finite."""
    from mamma_kit.evaluation.calibration import compare

    gt = ring(4, radius=4.5, height=1.6)
    placed = gt.transformed(rodrigues(np.array([0.0, 0.0, yaw])), np.array([*shift, 0.0]))
    res = compare(placed, gt, align="floor")
    assert res["aligned"] == "floor"
    assert res["worst"]["center_mm"] < 1e-3 and res["worst"]["rotation_deg"] < 1e-5, res["worst"]
    assert res["worst"]["reprojection_px_max"] < 1e-3 and res["worst"]["behind_camera_pct"] == 0
    tilted = placed.transformed(rodrigues(np.array([tilt, 0.0, 0.0])), np.zeros(3))
    res = compare(tilted, gt, align="floor")
    assert res["worst"]["rotation_deg"] > 0.5 * np.degrees(tilt), res["worst"]
    assert np.isfinite(res["worst"]["reprojection_px_mean"])


def test_unaligned_reprojection_counts_points_behind_the_camera():
    """Cameras turned half around (the same centres, looking the other way) see the test points
    behind them: they are counted, not projected into numbers of 1e18 px."""
    from mamma_kit.evaluation.calibration import compare

    gt = ring(4, radius=4.5, height=1.6)
    flip = np.diag([-1.0, 1.0, -1.0])  # half a turn about each camera's own vertical axis
    turned = Rig([c.copy(R=flip @ c.R, t=-(flip @ c.R) @ c.center) for c in gt])
    res = compare(turned, gt, align="none")
    for cam in res["cameras"].values():
        assert cam["behind_camera_pct"] == 100 and cam["reprojection_px_mean"] is None, cam
    assert res["worst"]["behind_camera_pct"] == 100 and res["worst"]["reprojection_px_max"] is None


@settings(max_examples=30, deadline=None)
@given(rv=st.lists(st.floats(-3, 3), min_size=3, max_size=3), t=st.lists(st.floats(-3, 3), min_size=3, max_size=3),
       yaw=st.lists(st.floats(-3, 3), min_size=2, max_size=2))
def test_floor_boards_define_z_up_and_the_origin(rv, t, yaw):
    """Whatever frame the rig is solved in, the floor boards map to the world the synthetic
    generator uses: origin board's corner at (0, 0, 0), printed faces up, floor at z = 0."""
    from mamma_kit.calibration.world import world_from_floor
    from mamma_kit.synth.board import R_WORLD_FLOOR_BOARD

    spec = load_board_spec("charuco-a1")
    R_frame, t_frame = rodrigues(np.array(rv)), np.array(t)  # world -> arbitrary rig frame
    # the origin board, and two more flat on the floor elsewhere, turned about Z
    poses_w = [(R_WORLD_FLOOR_BOARD, np.zeros(3))]
    for k, (a, pos) in enumerate(zip(yaw, ([1.2, 0.3, 0.0], [-0.8, -1.1, 0.0]))):
        poses_w.append((rodrigues(np.array([0, 0, a])) @ R_WORLD_FLOOR_BOARD, np.array(pos)))
    ev_R = np.stack([R_frame @ R for R, _ in poses_w])
    ev_t = np.stack([R_frame @ p + t_frame for _, p in poses_w])
    for boards in ([0], [0, 1, 2]):
        R_w, t_w, info = world_from_floor(ev_R, ev_t, 0, boards, spec.corners_b3)
        assert np.allclose(R_w @ R_frame, np.eye(3), atol=1e-9)
        assert np.allclose(R_w @ t_frame + t_w, 0, atol=1e-9)
        assert info["floor_boards"] == len(boards) and info["floor_flatness_mm"] < 1e-6


def test_far_weakly_tilted_views_do_not_send_the_focal_length_off():
    """Board detections of the demo capture's cam3 (board 4-5 m away, true fx = fy = 768.2 px at
    960x540): OpenCV's own start converged to fx 1750, fy 22700 px there, which left the camera
    unconnected; the multi-start with square pixels finds the real lens."""
    from mamma_kit.calibration.detect import Detections
    from mamma_kit.calibration.intrinsics import calibrate_camera

    data = Path(__file__).parent / "data"
    z = np.load(data / "far_board_cam3_detections.npz")
    det = Detections("cam3", "cam3.mp4", tuple(int(v) for v in z["size"]), z["times_f"], z["xy_fn2"],
                     z["n_markers_f"], int(z["rotation_deg"]), int(z["frame_step"]))
    res = calibrate_camera(det, load_board_spec(data / "far_board_spec.toml"))
    K = res.camera.K
    assert abs(K[0, 0] / 768.2 - 1) < 0.02 and abs(K[1, 1] / 768.2 - 1) < 0.02
    assert abs(K[0, 2] - 473.8) < 15 and abs(K[1, 2] - 266.9) < 15
    assert res.rms_px < 0.6
