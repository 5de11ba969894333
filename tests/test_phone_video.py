"""Phone files as phones store them (issue 41): frames shown as players show them (the display
matrix: rotations and mirrors), HLG HDR tone-mapped to SDR, capture.toml's rotation override, and
calibrations made at a codec-padded size."""

from __future__ import annotations

import numpy as np
import pytest

from mamma_kit.core.errors import UserError
from mamma_kit.video.colour import REFERENCE_WHITE_CD, hlg_inverse_oetf, pq_eotf
from mamma_kit.video.orientation import Orientation, display_matrix, from_display_matrix
from mamma_kit.video.reader import VideoReader
from mamma_kit.video.writer import VideoWriter

ALL = [Orientation(cw, m) for cw in (0, 90, 180, 270) for m in (False, True)]


def picture(h=96, w=64) -> np.ndarray:
    """A frame no turn or mirror leaves unchanged: a gradient and two coloured corners."""
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = np.linspace(20, 230, w)[None, :, None].astype(np.uint8)
    img[:20, :24] = (240, 30, 30)
    img[-16:, -12:] = (20, 200, 20)
    return img


def write(path, img, **kw):
    with VideoWriter(path, img.shape[1], img.shape[0], fps=30, crf=10, **kw) as w:
        for i in range(2):
            w.write_frame(img, i / 30)
    return path


def test_rotations_are_shown_as_opencv_shows_them(tmp_path):
    """OpenCV's VideoCapture turns frames by the display matrix (CAP_PROP_ORIENTATION_AUTO):
    for every rotation PyAV writes, the reader gives OpenCV's picture."""
    import av
    import cv2

    img = picture()
    for ccw in (90, -90, 180):
        p = tmp_path / f"r{ccw}.mp4"
        with av.open(str(p), "w") as c:  # PyAV's own display matrix, not display_matrix()
            vs = c.add_stream("libx264", rate=30)
            vs.width, vs.height, vs.pix_fmt = img.shape[1], img.shape[0], "yuv420p"
            vs.options = {"crf": "10"}
            vs.set_display_rotation(float(ccw))
            for pkt in vs.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(pkt)
            for pkt in vs.encode():
                c.mux(pkt)
        ok, bgr = cv2.VideoCapture(str(p)).read()
        assert ok
        t, ours = next(iter(VideoReader(p).frames()))
        assert ours.shape == bgr.shape
        assert np.abs(ours.astype(int) - bgr[..., ::-1]).mean() < 3  # codec noise; a wrong turn is ~60


def test_display_matrix_round_trip_for_all_eight_orientations():
    for o in ALL:
        assert from_display_matrix(display_matrix(o)) == o
        img = picture()
        assert np.array_equal(o.unapply(o.apply(img)), img)
    assert from_display_matrix(None) == Orientation()


@pytest.mark.parametrize("o", ALL, ids=lambda o: o.label().replace(" ", "-"))
def test_every_orientation_reads_upright(tmp_path, o):
    img = picture()
    p = write(tmp_path / "v.mov", img, codec="hevc", bit_depth=10, orientation=o)
    r = VideoReader(p)
    assert r.info.stored_size == o.stored_size(img.shape[1], img.shape[0])
    assert r.size == (img.shape[1], img.shape[0])
    assert (r.info.rotation_deg, r.info.mirrored, r.info.bit_depth, r.info.codec) == (o.cw, o.mirror, 10, "hevc")
    for _, out in r.frames():
        assert np.abs(out.astype(int) - img).mean() < 3


def test_capture_toml_rotation_overrides_the_file(tmp_path):
    from mamma_kit.core.io import write_toml
    from mamma_kit.core.workspace import Workspace

    img = picture()
    p = write(tmp_path / "v.mp4", img, orientation=Orientation(90))
    stored = VideoReader(p, rotation=0)
    assert stored.size == (img.shape[0], img.shape[1]) and stored.info.rotation_from == "capture.toml"
    _, s = next(iter(stored.frames()))
    assert np.abs(s.astype(int) - Orientation(90).unapply(img)).mean() < 3
    _, up = next(iter(VideoReader(p, rotation=90).frames()))
    assert np.abs(up.astype(int) - img).mean() < 3
    write_toml(tmp_path / "capture.toml", {"cameras": {"a": {"video": "v.mp4", "rotation": 270},
                                                       "b": {"video": "v.mp4", "rotation": "auto"}}})
    cams = Workspace(tmp_path).load_capture().cameras
    assert (cams["a"].rotation, cams["b"].rotation) == (270, None)
    write_toml(tmp_path / "capture.toml", {"cameras": {"a": {"video": "v.mp4", "rotation": 45}}})
    with pytest.raises(UserError, match="rotation = 45 is not one of auto, 0, 90, 180, 270"):
        Workspace(tmp_path).load_capture()


def test_hlg_transfer_meets_bt2408_reference_white():
    """BT.2408: HLG's 75 % signal is HDR reference white, 203 cd/m2 on the 1000 cd/m2 display
    (inverse OETF then the OOTF, gamma 1.2); PQ's 58 % is 203 cd/m2 too."""
    e = hlg_inverse_oetf(np.array([0.75]))[0]
    assert abs(1000 * e ** 1.2 - REFERENCE_WHITE_CD) < 1.0
    assert abs(pq_eotf(np.array([0.58]))[0] - REFERENCE_WHITE_CD) < 3.0


def test_hlg_video_reads_as_its_sdr_picture(tmp_path):
    img = picture()
    p = write(tmp_path / "hlg.mov", img, codec="hevc", bit_depth=10, hlg=True, orientation=Orientation(90))
    r = VideoReader(p)
    assert r.info.transfer == "hlg" and "HLG" in r.info.describe()
    _, out = next(iter(r.frames()))
    assert np.abs(out.astype(int) - img).mean() < 3
    _, grey = next(iter(r.frames(fmt="gray")))
    assert grey.shape == img.shape[:2]
    # read as if it were SDR (no tone map), the same file is far paler
    import av

    with av.open(str(p)) as c:
        raw = Orientation(90).apply(next(c.decode(video=0)).to_ndarray(format="rgb24"))
    assert np.abs(raw.astype(int) - img).mean() > 10


def calib_for(tmp_path, size, name="cam0"):
    from mamma_kit.core.calibfile import write_calibration
    from mamma_kit.core.camera import Camera, Rig

    w, h = size
    cams = [Camera(n, (w, h), np.array([[300.0, 0, w / 2], [0, 300.0, h / 2], [0, 0, 1]]), np.zeros(5), "radtan",
                   np.eye(3), np.array([i * 0.5, 0, 3.0])) for i, n in enumerate(("cam0", "cam1"))]
    return write_calibration(tmp_path / f"calib-{w}x{h}.toml", Rig(cams))


def test_codec_padded_calibration_loads_with_a_warning(tmp_path, cli):
    """A calibration at 208x368 for videos shown at 200x360 (a lab system that saw the codec's
    16-pixel blocks) loads with its K and a warning; 210x360 is not padding: one line, exit 2."""
    from mamma_kit.core.calibfile import read_calibration

    img = picture(360, 200)
    vids = [write(tmp_path / f"cam{i}.mov", img, codec="hevc", bit_depth=10, orientation=Orientation(90))
            for i in range(2)]
    r = cli("init", tmp_path / "ws", "--videos", *vids, "--calibration", calib_for(tmp_path, (208, 368)))
    assert r.code == 0, r
    err = " ".join(r.err.split())  # the log wraps long lines
    assert "padding to a multiple of 16" in err and "cropped at the right and bottom" in err
    assert "200x360, shown turned 90 deg" in err
    rig, _ = read_calibration(tmp_path / "ws" / "calibration.toml")
    assert rig["cam0"].size == (200, 360) and rig["cam0"].K[0, 2] == 104.0
    r = cli("init", tmp_path / "ws2", "--videos", *vids, "--calibration", calib_for(tmp_path, (210, 360)))
    assert r.code == 2
    assert "calibrates camera cam0 at 210x360 but cam0.mov is shown at 200x360" in " ".join(r.err.split())
    assert not (tmp_path / "ws2" / "capture.toml").exists()  # nothing written


def test_synth_writes_phone_like_files_on_request(tmp_path, cli):
    """A recipe's [rig.video]: HEVC Main10 HLG .mov, one camera portrait stored landscape with a
    display rotation of 90; the reader shows every video at its camera's calibrated size, upright
    (the ground-truth landmarks land on the person in the displayed frame)."""
    import tomllib

    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.io import write_toml
    from mamma_kit.core.tracks import LandmarkTracks
    from mamma_kit.synth.recipe import RECIPES_DIR

    recipe = tomllib.loads((RECIPES_DIR / "tiny.toml").read_text())
    recipe["rig"]["portrait"] = [True, False]
    recipe["rig"]["video"] = {"codec": "hevc", "bit_depth": 10, "transfer": "hlg", "rotation": [90, 0],
                              "container": "mov"}
    write_toml(tmp_path / "phone.toml", recipe)
    r = cli("synth", tmp_path / "phone.toml", "--out", tmp_path / "ws", "--frames", "3", "--quiet")
    assert r.code == 0, r
    rig, _ = read_calibration(tmp_path / "ws" / "gt" / "calibration.toml")
    for name, cw in (("cam0", 90), ("cam1", 0)):
        info = VideoReader(tmp_path / "ws" / "videos" / f"{name}.mov").info
        assert (info.width, info.height) == rig[name].size, name
        assert (info.rotation_deg, info.transfer, info.bit_depth, info.codec) == (cw, "hlg", 10, "hevc"), name
    assert rig["cam0"].size[1] > rig["cam0"].size[0]  # portrait, shown upright
    lt = LandmarkTracks.load(tmp_path / "ws" / "gt" / "landmarks" / "cam0.npz")
    _, img = next(iter(VideoReader(tmp_path / "ws" / "videos" / "cam0.mov").frames()))
    t = int(np.flatnonzero(lt.valid[:, 0])[0])
    xy = lt.xy[t, 0][lt.visibility[t, 0] > 0.5].round().astype(int)
    inside = (xy[:, 0] >= 0) & (xy[:, 1] >= 0) & (xy[:, 0] < img.shape[1]) & (xy[:, 1] < img.shape[0])
    xy = xy[inside]
    # the person is rendered on a bright-ish backdrop: the visible landmarks sit on pixels that differ
    # from the image's median colour far more often than random pixels do
    med = np.median(img.reshape(-1, 3), 0)
    on = np.abs(img[xy[:, 1], xy[:, 0]].astype(float) - med).sum(1)
    rng = np.random.default_rng(0)
    rand = np.abs(img[rng.integers(0, img.shape[0], 500), rng.integers(0, img.shape[1], 500)].astype(float)
                  - med).sum(1)
    assert np.median(on) > 2 * np.median(rand)


def test_frames_scaled_while_decoding_match_the_full_frame_scaled(tmp_path):
    """frames(max_side=...): the displayed frame at working_size (a 4K frame tracked at half size),
    the same picture as the full frame scaled afterwards; frames within max_side come as they are."""
    import cv2

    img = np.repeat(np.repeat(picture(96, 64), 4, 0), 4, 1)  # 256x384 displayed
    p = write(tmp_path / "big.mov", img, codec="hevc", bit_depth=10, orientation=Orientation(90))
    r = VideoReader(p)
    assert r.working_size(192) == (128, 192) and r.working_size(384) == (256, 384)
    _, small = next(iter(r.frames(max_side=192)))
    _, full = next(iter(r.frames()))
    assert small.shape == (192, 128, 3)
    ref = cv2.resize(full, (128, 192), interpolation=cv2.INTER_AREA)
    assert np.abs(small.astype(int) - ref).mean() < 3
    _, same = next(iter(r.frames(max_side=384)))
    assert np.array_equal(same, full)
