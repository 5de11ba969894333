"""Qualisys QTM calibrations (.qca.txt): the real Pose2Sim lab file converts to a rig that looks
at its own middle with world Z up; a synthetic file written from a known rig projects exactly
like it; a broken file is one clear UserError; `init --calibration` takes the file."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from conftest import make_ring_rig
from mamma_kit.calibration.formats import (READ_FORMATS, convert, infer_format, read_rig,
                                           rig_projection_difference, write_rig)
from mamma_kit.core.calibfile import read_calibration
from mamma_kit.core.camera import Camera, Rig
from mamma_kit.core.errors import UserError

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "real" / "pose2sim-multiperson"
QCA = REAL / "calibration" / "Calib.qca.txt"


@pytest.fixture
def real_qca() -> Path:
    if not QCA.is_file():
        pytest.skip(f"{QCA} not present (CI has shared/ beside the repo)")
    return QCA


def _axes_meet(rig: Rig) -> np.ndarray:
    """The world point closest (least squares) to every camera's optical axis."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in rig:
        d = c.R[2]  # the optical axis (camera z) in world coordinates
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c.center
    return np.linalg.solve(A, b)


# ---- the real file ---------------------------------------------------------------------
def test_real_file_converts_to_a_rig_that_looks_at_its_middle(real_qca, tmp_path, cli):
    assert infer_format(real_qca) == "qualisys"
    out = tmp_path / "calibration.toml"
    r = cli("calib", "convert", real_qca, out, "--json")
    assert r.code == 0, r
    assert json.loads(r.out)["from"] == "qualisys"
    rig, _ = read_calibration(out)
    assert rig.names == ["cam01", "cam02", "cam03", "cam04"]
    meet = _axes_meet(rig)
    centroid = rig.centers().mean(0)
    for c in rig:
        w, h = c.size
        assert (w, h) == (1088, 1920)
        assert c.model == "radtan" and np.abs(c.dist).max() < 0.2
        assert c.K[0, 0] == pytest.approx(1680, rel=0.01) and c.K[1, 1] == pytest.approx(1680, rel=0.01)
        centre = np.array([(w - 1) / 2, (h - 1) / 2])
        assert np.all(np.abs(c.K[:2, 2] - centre) < 0.1 * np.array([w, h]))
        # Z up: cameras hang 1.5-2.3 m above the floor, and the image's up is the world's up
        assert 1.5 < c.center[2] < 2.3
        assert -c.R[1] @ [0, 0, 1.0] > 0.7
        # the middle of the rig is in front of every camera and in its image; the cameras
        # tilt down, so the camera centroid (at their height) sits above the image centre,
        # and the point their axes meet at (below it, over the treadmill) lands on the centre
        z = c.to_camera(centroid)[2]
        uv = c.project(centroid)
        assert z > 1.0 and 0 <= uv[0] < w and 0 <= uv[1] < h / 2
        assert abs(uv[0] - centre[0]) < 0.25 * w
        assert c.to_camera(meet)[2] > 1.0
        assert np.all(np.abs(c.project(meet) - centre) < 0.1 * np.array([w, h]))
    # the axes meet over the floor, below the cameras, near the centroid's vertical
    assert 0 < meet[2] < rig.centers()[:, 2].min()
    assert np.linalg.norm(meet[:2] - centroid[:2]) < 0.5


def test_init_takes_the_qualisys_file(real_qca, tmp_path, cli):
    from mamma_kit.pipeline import capture_to_smplx

    vids = [REAL / "videos" / f"cam0{i}.mp4" for i in range(1, 5)]
    if not all(v.is_file() for v in vids):
        pytest.skip(f"{REAL / 'videos'} not present")
    ws = tmp_path / "ws"
    r = cli("init", ws, "--videos", *vids, "--calibration", real_qca, "--json")
    assert r.code == 0, r
    assert json.loads(r.out)["calibration"] == str(ws / "calibration.toml")
    rig, _ = read_calibration(ws / "calibration.toml")
    assert rig_projection_difference(read_rig(real_qca), rig, np.random.default_rng(0).uniform(-2, 2, (500, 3))) < 1e-6
    summary = capture_to_smplx(ws, to_stage="calibrate", progress=False)
    assert summary["stages"]["calibrate"]["status"] == "provided"
    # board videos and a calibration together are refused, and so is a calibration at another size
    r = cli("init", tmp_path / "both", "--videos", *vids, "--board-videos", *vids, "--board", "charuco-a1",
            "--calibration", real_qca)
    assert r.code == 2 and "both board videos and --calibration" in r.err
    landscape = tmp_path / "landscape.qca.txt"
    _write_qca(Rig([c.copy(size=(1920, 1088)) for c in read_rig(real_qca)]), landscape)
    r = cli("init", tmp_path / "other", "--videos", *vids, "--calibration", landscape)
    assert r.code == 2 and "1920x1088" in r.err and not (tmp_path / "other" / "capture.toml").exists()


# ---- synthetic round trip -------------------------------------------------------------
_QCA_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


def _num(v) -> str:
    return repr(float(v))  # shortest text that reads back as the same float


def _write_qca(rig: Rig, path: Path, offsets=None) -> None:
    """A minimal QTM calibration from a rig, following the layout the reader documents;
    ``offsets`` gives each camera's fov_video (left, top) on its sensor."""
    cams = []
    for i, c in enumerate(rig):
        left, top = (offsets or {}).get(c.name, (0, 0))
        w, h = c.size
        k1, k2, p1, p2, k3 = list(c.dist) + [0.0] * (5 - len(c.dist))
        R_cam_world = (_QCA_TO_OPENCV @ c.R).T  # Qualisys camera axes -> world
        rot = " ".join(f'r{a + 1}{b + 1}="{_num(R_cam_world[b, a])}"' for a in range(3) for b in range(3))
        x, y, z = c.center * 1000
        cams.append(
            f'<camera active="1" avg-residual="0.4" model="Miqus Video" serial="{c.name}" viewrotation="0">\n'
            f'<fov_video left="{left}" top="{top}" right="{left + w - 1}" bottom="{top + h - 1}"/>\n'
            f'<transform {rot} x="{_num(x)}" y="{_num(y)}" z="{_num(z)}"/>\n'
            f'<intrinsic focalLengthU="{_num(c.K[0, 0] * 64)}" focalLengthV="{_num(c.K[1, 1] * 64)}" '
            f'centerPointU="{_num((c.K[0, 2] + left) * 64)}" centerPointV="{_num((c.K[1, 2] + top) * 64)}" skew="0" '
            f'sensorMinU="0" sensorMaxU="{(left + w - 1) * 64}" sensorMinV="0" sensorMaxV="{(top + h - 1) * 64}" '
            f'radialDistortion1="{_num(k1)}" radialDistortion2="{_num(k2)}" radialDistortion3="{_num(k3)}" '
            f'tangentalDistortion1="{_num(p1)}" tangentalDistortion2="{_num(p2)}"/>\n</camera>')
    path.write_text('<?xml version="1.0" encoding="UTF-8"?>\n<calibration type="regular">\n<cameras>\n'
                    + "\n".join(cams) + "\n</cameras>\n</calibration>\n")


def test_synthetic_file_projects_like_the_rig_it_was_written_from(tmp_path):
    rig = make_ring_rig(4, size=(1080, 1920), f=1500.0, dist=[-0.05, 0.12, 0.0007, -0.0004, 0.01], seed=3)
    p = tmp_path / "rig.qca.txt"
    # two cameras record a window of their sensor: the centre point is on the whole sensor
    _write_qca(rig, p, offsets={"cam1": (64, 32), "cam3": (10, 300)})
    back = read_rig(p)
    assert back.names == rig.names and [c.size for c in back] == [c.size for c in rig]
    rng = np.random.default_rng(0)
    X = np.c_[rng.uniform(-1.5, 1.5, (2000, 2)), rng.uniform(0, 2, 2000)]
    assert rig_projection_difference(rig, back, X) < 1e-6
    for a, b in zip(rig, back):
        assert np.allclose(a.center, b.center, atol=1e-9) and np.allclose(a.K, b.K, atol=1e-9)


def test_qualisys_is_read_only(tmp_path, ring_rig):
    assert "qualisys" in READ_FORMATS
    with pytest.raises(UserError, match="read-only"):
        write_rig(ring_rig, tmp_path / "out.qca.txt")
    src = tmp_path / "calibration.toml"
    write_rig(ring_rig, src)
    with pytest.raises(UserError, match="read-only"):
        convert(src, tmp_path / "x.json", None, "qualisys")


# ---- broken files ---------------------------------------------------------------------
def _one_camera(tmp_path: Path) -> str:
    cam = Camera("c1", (640, 480), [[500, 0, 320], [0, 500, 240], [0, 0, 1]], np.zeros(5), "radtan",
                 np.eye(3), [0, 0, 3.0])
    p = tmp_path / "ok.qca.txt"
    _write_qca(Rig([cam]), p)
    return p.read_text()


@pytest.mark.parametrize("breakage,message", [
    (lambda s: s[: len(s) // 2], "not valid XML"),
    (lambda s: "<calibration/>", "no <calibration><cameras><camera>"),
    (lambda s: s.replace(' serial="c1"', ""), "no 'serial'"),
    (lambda s: s.replace(' focalLengthV="', ' fLV="'), "missing 'focalLengthV'"),
    (lambda s: s.replace(' x="', ' x="abc" xx="'), "'x' is not a number"),
    (lambda s: s.replace("<fov_video", "<fov_other"), "no <fov_video>"),
    (lambda s: s.replace(' r11="1.0"', ' r11="2.0"'), "not a rotation"),
    (lambda s: s.replace(' centerPointV="15360.0"', ' centerPointV="-640"'), "principal point"),
])
def test_broken_file_is_one_clear_user_error(tmp_path, cli, breakage, message):
    text = _one_camera(tmp_path)
    p = tmp_path / "bad.qca.txt"
    p.write_text(breakage(text))
    assert p.read_text() != text
    with pytest.raises(UserError, match=re.escape(message)) as e:
        read_rig(p)
    assert "\n" not in e.value.line()
    r = cli("calib", "convert", p, tmp_path / "out.toml")
    assert r.code == 2 and "Traceback" not in r.err and r.err.strip().count("\n") == 0, r
