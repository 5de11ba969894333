"""The board-only recipe (a calibration session, no people) synthesises a workspace that
`mamma-kit calibrate` accepts and calibrates (issue 23: capture.toml said people = 0 and
calibrate refused it as "not a count")."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import write_toml
from mamma_kit.core.workspace import Workspace

RECIPE = Path(__file__).resolve().parents[1] / "recipes" / "board-only.toml"


def test_people_zero_is_a_count(tmp_path):
    write_toml(tmp_path / "capture.toml", {"capture": {"name": "b", "people": 0},
                                           "cameras": {"cam0": {"video": "videos/cam0.mp4"}}})
    assert Workspace(tmp_path).load_capture().people == 0
    write_toml(tmp_path / "capture.toml", {"capture": {"name": "b", "people": -1},
                                           "cameras": {"cam0": {"video": "videos/cam0.mp4"}}})
    with pytest.raises(UserError, match="is not a count"):
        Workspace(tmp_path).load_capture()


@pytest.mark.slow
def test_board_only_workspace_calibrates(tmp_path, cli):
    """The recipe as shipped (4 cameras on a 4.5 m ring, A1 board, 30 s session), rendered at
    half resolution and, to keep the test short, at 5 frames per second instead of 30 (150
    frames per camera: one run measured rms 0.17 px, focal 0.38 %, centres 12 mm, rotations
    0.33 deg, tilt 1.3 deg, each well inside its bound below). Half resolution is the smallest at which the
    board, 4.5 m away, is still found often enough (a quarter leaves 9 px squares)."""
    recipe = tomllib.loads(RECIPE.read_text())
    recipe["fps"] = 5.0
    write_toml(tmp_path / "board-only.toml", recipe)
    ws = tmp_path / "ws"
    r = cli("synth", tmp_path / "board-only.toml", "--out", ws, "--frames", "2", "--scale", "0.5", "--quiet")
    assert r.code == 0, r
    assert tomllib.loads((ws / "capture.toml").read_text())["capture"]["people"] == 0
    r = cli("calibrate", ws, "--no-figures", "--json", "--quiet")
    assert r.code == 0, r
    res = json.loads(r.out)
    assert set(res["cameras"]) == {"cam0", "cam1", "cam2", "cam3"}
    assert res["rms_px"] < 0.4, res["rms_px"]
    r = cli("eval", ws, "--json")
    assert r.code == 0, r
    ev = json.loads(r.out)["calibration"]
    # 960x540 at 4.5 m (squares of ~19 px; one run measured focal 0.33 %, centres 9 mm,
    # rotations 0.4 deg relative to the ground truth, world tilt 0.9 deg from one camera's
    # floor board)
    rel = ev["relative"]["worst"]
    assert rel["focal_pct"] < 1.0, rel
    assert rel["center_mm"] < 25.0, rel
    assert rel["rotation_deg"] < 0.8, rel
    assert ev["world_frame"]["tilt_deg"] < 2.5, ev["world_frame"]
