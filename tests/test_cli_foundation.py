"""The CLI's contract: --version, doctor --json, calib convert, and one-line user errors (exit 2)."""

import json

import numpy as np

from mamma_kit.calibration.formats import read_rig, write_rig
from mamma_kit.core.io import read_toml, write_toml


def _one_clear_line(res):
    lines = [ln for ln in res.err.strip().splitlines() if ln.strip()]
    assert res.code == 2, res
    assert len(lines) == 1, res.err
    assert "Traceback" not in res.err
    return lines[0]


def test_version(cli):
    res = cli("--version")
    assert res.code == 0 and res.out.startswith("mamma-kit ")


def test_doctor_json_is_valid(cli):
    res = cli("doctor", "--json")
    data = json.loads(res.out)
    assert data["mamma_kit"] and data["packages"]["numpy"]
    assert any(c["name"] == "opencv aruco" and c["ok"] for c in data["checks"])


def test_calib_convert_cli(cli, tmp_path, ring_rig):
    src = tmp_path / "calibration.toml"
    write_rig(ring_rig, src)
    res = cli("calib", "convert", src, tmp_path / "easy", "--to", "easymocap", "--json")
    assert res.code == 0, res
    assert json.loads(res.out)["to"] == "easymocap"
    back = read_rig(tmp_path / "easy" / "intri.yml")
    assert np.allclose(back.centers(), ring_rig.centers())


def test_missing_file_is_one_line(cli, tmp_path):
    line = _one_clear_line(cli("calib", "convert", tmp_path / "nope.toml", tmp_path / "o.json"))
    assert "nope.toml" in line


def test_calibration_missing_field_is_one_line(cli, tmp_path, ring_rig):
    src = tmp_path / "calibration.toml"
    write_rig(ring_rig, src)
    data = read_toml(src)
    del data["cameras"]["cam2"]["K"]
    write_toml(src, data)
    line = _one_clear_line(cli("calib", "convert", src, tmp_path / "o.json"))
    assert "cam2" in line and "'K'" in line


def test_calibration_malformed_field_is_one_line(cli, tmp_path, ring_rig):
    src = tmp_path / "calibration.toml"
    write_rig(ring_rig, src)
    data = read_toml(src)
    data["cameras"]["cam1"]["t"] = [1.0, 2.0]
    write_toml(src, data)
    line = _one_clear_line(cli("calib", "convert", src, tmp_path / "o.json"))
    assert "cam1" in line and "'t'" in line


def test_calibration_missing_camera_is_one_line(tmp_path, ring_rig):
    from mamma_kit.core.calibfile import check_rig_covers, read_calibration
    from mamma_kit.core.errors import UserError
    import pytest

    src = tmp_path / "calibration.toml"
    write_rig(ring_rig, src)
    rig, _ = read_calibration(src)
    with pytest.raises(UserError, match="no camera cam7"):
        check_rig_covers(rig, ["cam0", "cam7"], src)


def test_corrupt_toml_is_one_line(cli, tmp_path):
    p = tmp_path / "calibration.toml"
    p.write_text("[cameras.cam0\nsize = [1, 2]\n")
    line = _one_clear_line(cli("calib", "convert", p, tmp_path / "o.json", "--from", "mamma-kit"))
    assert "not valid TOML" in line


def test_unknown_format_is_one_line(cli, tmp_path, ring_rig):
    src = tmp_path / "calibration.toml"
    write_rig(ring_rig, src)
    line = _one_clear_line(cli("calib", "convert", src, tmp_path / "o.bin"))
    assert "--from/--to" in line
