"""What real board recordings bring (issue 23): boards seen from behind, frame sampling that
adapts to the video, shared clocks found from a timestamps file or the videos' own stamps,
Caliscope's board file."""

from __future__ import annotations

import numpy as np
import pytest

from mamma_kit.calibration.board import BoardSpec, load_board_spec
from mamma_kit.calibration.clocks import find_timestamps_file, read_timestamps, shared_clock_from_videos
from mamma_kit.calibration.detect import BoardFinder, frame_step_for
from mamma_kit.core.errors import UserError

SPEC = BoardSpec(5, 7, 0.04, 0.03, "DICT_4X4_50", name="t")


def _front_image(spec: BoardSpec, p: int = 40, margin: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """The printed pattern on a white page, and its chessboard corners' pixels (N, 2)."""
    img = spec.image(p, margin)
    n = spec.squares_x - 1
    j = np.arange(spec.n_corners)
    # corner j lies between pixels: at (col + 1) * p + margin - 0.5 in pixel-centre coordinates
    xy = np.stack([(j % n + 1) * p + margin - 0.5, (j // n + 1) * p + margin - 0.5], -1)
    return img, xy


@pytest.mark.parametrize("inverted", [False, True])
def test_board_seen_from_behind_is_found_with_its_own_corner_ids(inverted):
    spec = SPEC.with_(inverted=inverted)
    front, xy_front = _front_image(spec)
    finder = BoardFinder(spec)
    xy, n_markers, back = finder.detect_any_side(front)
    assert not back and np.nanmax(np.abs(xy - xy_front)) < 0.2
    # from behind the print is its mirror image: nothing reads the right way round ...
    behind = np.ascontiguousarray(front[:, ::-1])
    xy0, _ = finder.detect(behind)
    assert np.isfinite(xy0[:, 0]).sum() < 6
    # ... but the mirrored search finds every corner, in the stored image's pixels, by id
    xy, n_markers, back = finder.detect_any_side(behind)
    assert back and n_markers > 0
    expect = xy_front.copy()
    expect[:, 0] = behind.shape[1] - 1 - expect[:, 0]
    assert np.isfinite(xy[:, 0]).all()
    assert np.abs(xy - expect).max() < 0.2
    # without the mirrored search the back side stays unseen
    _, _, back = BoardFinder(spec, mirrored=False).detect_any_side(behind)
    assert not back


def test_short_and_low_rate_videos_are_read_whole():
    assert frame_step_for(6.0, 10.0, 111) == 1  # a 6 fps webcam
    assert frame_step_for(30.0, 10.0, 300) == 1  # a 10 s clip
    assert frame_step_for(30.0, 10.0, 900) == 2  # 30 s: never fewer than ~400 frames
    assert frame_step_for(60.0, 10.0, 7200) == 6  # long: about 10 per second, as before


def _write_csv(path, rows, header="sync_index,cam_id,frame_time"):
    path.write_text(header + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")


def test_timestamps_file_gives_frames_of_one_sync_index_one_time(tmp_path):
    rows = []
    for si in range(5):
        for cam, jitter in ((0, 0.0), (1, 0.004), (2, -0.003)):
            if cam == 2 and si == 0:
                continue  # cam 2 started one frame late
            rows.append((si + 10, cam, 100.0 + si / 6 + jitter))
    rows.append((14, 1, 100.0 + 4 / 6 + 0.001))  # out of order rows are fine: time orders them
    rows = rows[:-1]
    f = tmp_path / "timestamps.csv"
    _write_csv(f, rows[::-1])
    sc = read_timestamps(f, {"cam_0": 5, "cam_1": 5, "cam_2": 4})
    assert sc.source == "timestamps file"
    for n in ("cam_0", "cam_1"):
        assert np.allclose(sc.frame_times["cam_0"], sc.frame_times[n])
    assert np.allclose(sc.frame_times["cam_2"], sc.frame_times["cam_0"][1:])
    assert np.all(np.diff(sc.frame_times["cam_0"]) > 0.1)
    # a frame stamped far from its sync_index's others keeps its own time
    _write_csv(f, [(0, 0, 1.0), (0, 1, 1.05), (1, 0, 1.2), (1, 1, 1.2)])
    sc = read_timestamps(f, {"cam_0": 2, "cam_1": 2})
    assert sc.frame_times["cam_0"][0] != sc.frame_times["cam_1"][0]
    assert sc.frame_times["cam_0"][1] == sc.frame_times["cam_1"][1]
    # found beside the videos; named cameras by their number
    (tmp_path / "cam_0.mp4").touch()
    (tmp_path / "cam_1.mp4").touch()
    assert find_timestamps_file({"cam_0": tmp_path / "cam_0.mp4", "cam_1": tmp_path / "cam_1.mp4"}) == f
    sc = read_timestamps(f, {"left0": 2, "right1": 2})
    assert set(sc.frame_times) == {"left0", "right1"}


@pytest.mark.parametrize("rows, n_frames, words", [
    ([(0, 0, 1.0)], {"cam_0": 2}, ["lists 1 frames of camera cam_0", "video holds 2"]),
    ([(0, 7, 1.0)], {"cam_0": 1}, ["no rows for camera cam_0", "cam_ids: 7"]),
])
def test_timestamps_file_that_does_not_fit_the_videos_is_one_clear_error(tmp_path, rows, n_frames, words):
    f = tmp_path / "timestamps.csv"
    _write_csv(f, rows)
    with pytest.raises(UserError) as e:
        read_timestamps(f, n_frames)
    for w in words:
        assert w in e.value.line()
    _write_csv(f, rows, header="a,b,c")
    with pytest.raises(UserError, match="expected the columns sync_index, cam_id, frame_time"):
        read_timestamps(f, n_frames)


def test_videos_stamped_on_one_absolute_clock_share_it():
    t = np.arange(100) / 30.0
    # phones: every video starts at zero, which says nothing about their clocks
    assert shared_clock_from_videos({"a": t, "b": t}) is None
    # a recorder stamping every frame on its session clock
    sc = shared_clock_from_videos({"a": 5000.0 + t, "b": 5000.2 + t})
    assert sc is not None and sc.frame_times is None and "one absolute clock" in sc.detail
    # absolute but apart (one video recorded after the other): not one session
    assert shared_clock_from_videos({"a": 5000.0 + t, "b": 6000.0 + t}) is None


def test_caliscope_board_file_is_read(tmp_path):
    (tmp_path / "charuco.toml").write_text(
        'columns = 4\nrows = 5\nboard_height = 11.0\nboard_width = 8.5\ndictionary = "DICT_4X4_1000"\n'
        'units = "inch"\naruco_scale = 0.75\nsquare_size_override_cm = 5.4\ninverted = true\n')
    s = load_board_spec(tmp_path / "charuco.toml")
    assert (s.squares_x, s.squares_y, s.square_m, s.marker_m) == (4, 5, 0.054, 0.0405)
    assert s.dictionary == "DICT_4X4_1000" and s.inverted
