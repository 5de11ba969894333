"""A synchronised board session calibrates without --synced: the timestamps.csv beside the
videos (as Caliscope writes it) says the cameras share one clock (issue 23)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mamma_kit.calibration.board import load_board_spec
from mamma_kit.core.io import write_toml
from mamma_kit.synth.board import render_board_session
from conftest import make_ring_rig


@pytest.mark.slow
def test_synchronised_session_calibrates_without_synced(tmp_path, cli):
    rig = make_ring_rig(n=3, radius=1.8, height=1.4, size=(480, 360), f=430.0, dist=[-0.12, 0.05, 0.0, 0.0, 0.0])
    spec = load_board_spec("charuco-a1")
    # a synchronised rig: every camera's frame k at the same instant; the board keeps moving
    # (few still holds), so only the shared clock connects the cameras well
    info = render_board_session(tmp_path / "v", rig, spec, seed=3, duration_s=24.0, fps=5.0, n_closeups=3,
                                floor_pose=False, supersample=2, progress=False, hold_s=(0.3, 0.5))
    rows = ["sync_index,cam_id,frame_time"]
    for c, n in enumerate(rig.names):
        t = np.asarray(info["ref_times"][n]) + 1000.0 + 0.002 * c  # a recorder's stamps, with jitter
        rows += [f"{k},{c},{tk:.6f}" for k, tk in enumerate(t)]
    (tmp_path / "v" / "timestamps.csv").write_text("\n".join(rows) + "\n")
    write_toml(tmp_path / "board.toml", spec.to_dict())
    videos = [tmp_path / "v" / f"{n}.mp4" for n in rig.names]
    r = cli("calibrate", *videos, "--board", tmp_path / "board.toml", "--out", tmp_path / "c.toml", "--no-figures",
            "--json", "--no-floor")
    assert r.code == 0, r
    assert "shared clocks from timestamps.csv" in r.err and "no --synced needed" in r.err
    res = json.loads(r.out)
    assert res["timing"].startswith("shared clocks from timestamps.csv")
    assert res["events"]["sync"] > 0
    assert set(res["cameras"]) == set(rig.names) and res["rms_px"] < 0.4
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.evaluation.calibration import compare

    est, _ = read_calibration(tmp_path / "c.toml")
    rel = compare(est, rig, align="similarity")["worst"]
    assert rel["focal_pct"] < 1.0 and rel["center_mm"] < 25.0 and rel["rotation_deg"] < 0.6, rel
