"""A board session where one camera sees the board only from behind (issue 23).

The board is printed on both sides (`mamma-kit board --double-sided`): the camera behind
the person holding it sees the back, the mirror image of the front at the same 3D
corners. `mamma-kit calibrate` finds it in the mirrored image, uses those views as views of
the same corners, calibrates every camera and says which camera's views were seen from
behind.

Fast setting: 4 cameras at 640x480 on a 2 m ring, an A3 board, 48 s at 5 frames per
second, no floor board (a face-up floor board would show the camera behind its front),
cameras on one clock (--synced: at 5 fps too few still holds are found in every camera to
pair them without it). The issue-5 targets (focal 0.2 %, principal point 1 px, rotation
0.05 deg, centre 2 mm) are for iPhone-like resolution and a full session; here the
tolerances are those of tests/test_calibration.py's small session (principal point 5 px:
3.7 px measured on a front camera), and the camera behind must be calibrated as well as
the cameras that see the front.
"""

from __future__ import annotations

import contextlib
import io
import json
import re

import numpy as np
import pytest

from mamma_kit.calibration.board import load_board_spec
from mamma_kit.core.calibfile import read_calibration
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import write_toml
from mamma_kit.evaluation.calibration import compare
from mamma_kit.synth.board import render_board_session
from mamma_kit.synth.recipe import load_recipe
from conftest import make_ring_rig

BEHIND = "cam3"


@pytest.fixture(scope="module")
def behind_session(tmp_path_factory):
    from mamma_kit.cli.app import main

    root = tmp_path_factory.mktemp("behind")
    rig = make_ring_rig(4, radius=2.0, height=1.5, size=(640, 480), f=500.0,
                        dist=[-0.1, 0.04, 0.0005, -0.0003, 0.0], seed=4)
    spec = load_board_spec("charuco-a3")
    info = render_board_session(root / "v", rig, spec, seed=5, duration_s=48.0, fps=5.0, n_closeups=5,
                                floor_pose=False, supersample=2, progress=False, back="mirror", behind=[BEHIND])
    write_toml(root / "board.toml", spec.to_dict())
    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(["calibrate", *(str(p) for p in info["videos"].values()), "--board", str(root / "board.toml"),
                  "--out", str(root / "c.toml"), "--no-figures", "--no-floor", "--synced", "--json"])
        except SystemExit as e:
            code = e.code or 0
    return {"rig": rig, "info": info, "code": code, "out": out.getvalue(), "err": err.getvalue(),
            "calibration": root / "c.toml"}


@pytest.mark.slow
def test_the_camera_behind_sees_only_the_back(behind_session):
    info = behind_session["info"]
    seen = info["visible"][BEHIND] > 0.5
    assert seen.sum() >= 20
    assert info["from_behind"][BEHIND][seen].all()
    for n in ("cam0", "cam1", "cam2"):
        assert not info["from_behind"][n][info["visible"][n] > 0.5].all()


@pytest.mark.slow
def test_every_camera_calibrates_the_one_behind_as_well_as_the_others(behind_session):
    s = behind_session
    assert s["code"] == 0, s["err"][-2000:]
    res = json.loads(s["out"])
    assert set(res["cameras"]) == set(s["rig"].names)
    est, diag = read_calibration(s["calibration"])
    rel = compare(est, s["rig"], align="similarity")["cameras"]
    # measured (worst camera): focal 0.29 %, principal point 3.7 px, rotation 0.45 deg, centre 9.8 mm
    limits = {"focal_pct": 0.5, "principal_point_px": 5.0, "rotation_deg": 0.6, "center_mm": 20.0}
    for n, e in rel.items():
        for k, lim in limits.items():
            assert e[k] < lim, (n, k, e)
    # the camera behind is no worse than the cameras that see the front: within 1.5 x their worst,
    # or under half the tolerance, where a ratio of two small errors is noise. The same seeds gave
    # other figures on another machine and package set (unpinned opencv, numpy): 0.08 %, 0.95 px,
    # 0.22 deg, 6.1 mm against front worsts of 0.29 %, 3.7 px, 0.45 deg, 9.8 mm then; 0.17 %, 1.0 px,
    # 0.13 deg, 6.7 mm against 0.11 %, 2.7 px, 0.36 deg, 8.7 mm with opencv 5.1.0.95, numpy 2.4.6
    for k, lim in limits.items():
        front = max(rel[n][k] for n in rel if n != BEHIND)
        assert rel[BEHIND][k] <= max(1.5 * front, 0.5 * lim), (k, rel[BEHIND][k], front)
    # the camera behind is tied to the rig by views it shares with the others from behind
    assert res["cameras"][BEHIND]["shared_views"] >= 2


@pytest.mark.slow
def test_diagnostics_say_the_views_were_seen_from_behind(behind_session):
    s = behind_session
    assert s["code"] == 0, s["err"][-2000:]
    res = json.loads(s["out"])
    cam = res["cameras"][BEHIND]
    # from behind but while the board turns between holds (measured: 50 of 60 frames); the
    # cameras in front see its back only now and then
    assert cam["frames_detected"] > 0 and cam["frames_seen_from_behind"] >= 0.8 * cam["frames_detected"]
    for n in ("cam0", "cam1", "cam2"):
        assert res["cameras"][n]["frames_seen_from_behind"] <= 0.5 * res["cameras"][n]["frames_detected"]
    _, diag = read_calibration(s["calibration"])
    assert diag["cameras"][BEHIND]["frames_seen_from_behind"] == cam["frames_seen_from_behind"]
    # the log says it in words (rich wraps long lines: compare with whitespace joined)
    text = " ".join(s["err"].split())
    m = re.search(rf"{BEHIND}: (\d+) of (\d+) board views are seen from behind \(mirrored back side\)", text)
    assert m and int(m.group(1)) >= 0.8 * int(m.group(2)) > 0, text[-1500:]


def test_recipe_puts_cameras_behind_the_board(tmp_path):
    base = (tmp_path / "r.toml")
    text = ('name = "b"\nduration_s = 1.0\n[rig]\ncount = 3\n[people]\ncount = 0\n'
            '[board]\nspec = "charuco-a3"\nback = "mirror"\nbehind = ["cam2"]\n')
    base.write_text(text)
    r = load_recipe(base)
    assert r.board["back"] == "mirror" and r.board["behind"] == ["cam2"]
    for bad, words in (('behind = ["cam7"]', "no camera cam7"), ('back = "glass"', "not one of"),
                       ('behind = ["cam0", "cam1", "cam2"]', "at least one camera")):
        key = bad.split(" ")[0]
        base.write_text("\n".join(ln for ln in text.splitlines() if not ln.startswith(key)) + "\n" + bad + "\n")
        with pytest.raises(UserError, match=words):
            load_recipe(base)
