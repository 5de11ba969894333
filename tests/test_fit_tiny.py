"""End to end on the tiny recipe: render, noisy ground-truth landmarks, `mamma-kit fit`,
`mamma-kit eval`, against the recipe's ground truth.

tiny has two cameras facing each other across the person (3.5 m away, 320x240): each
landmark is seen along nearly the same line from both sides, so depth along that line
comes mostly from the body model. Landmarks: 1.2 % of the box height of Gaussian noise and
5 % outliers. Stated tolerance: MPJPE <= 45 mm over all 55 joints and <= 35 mm over the
22 body joints (measured: about 31 and 24 mm).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

MPJPE_MAX_MM = 45.0
MPJPE_BODY_MAX_MM = 35.0


@pytest.fixture(scope="module")
def tiny_fit(tmp_path_factory):
    from mamma_kit.cli.app import main
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.fit import install_gt_calibration_and_timing

    ws_dir = tmp_path_factory.mktemp("tiny") / "ws"

    def run(*args):
        try:
            main([str(a) for a in args])
        except SystemExit as e:
            assert e.code in (0, None), args

    run("synth", "tiny", "--out", ws_dir, "--no-board", "-q")
    ws = Workspace(ws_dir)
    install_gt_calibration_and_timing(ws)
    run("landmarks", ws_dir, "--source", "gt", "--noise", "1.2%", "--outliers", "0.05", "-q")
    return ws


def test_tiny_fit_recovers_joints(tiny_fit, cli):
    ws = tiny_fit
    r = cli("fit", ws.root, "--json", "-q")
    assert r.code == 0, r
    rep = json.loads(r.out)
    assert rep["stages"] == 4 and rep["persons"][0]["frames_observed"] == rep["frames"]
    assert set(rep["stage_stats"]) >= {"init", "stage1", "stage2", "stage3"}
    assert rep["checks"]["passed"] and rep["checks"]["flags"] == [], rep["checks"]  # a good capture flags nothing
    # every view's landmarks fit to about the noise level (sigma ~2 px here)
    for cam, e in rep["reprojection_px"].items():
        assert e["median"] < 4.0, (cam, e)

    from mamma_kit.core.smplxfile import read_smplx_result

    res = read_smplx_result(ws.person_file(0))
    assert res.producer["reference"] == "cam0" and res.joints.shape == (rep["frames"], 55, 3)
    assert np.all(np.diff(res.frame_times) > 0)

    r = cli("eval", ws.root, "--only", "fit", "--json")
    assert r.code == 0, r
    ev = json.loads(r.out)["fit"]
    assert ev["time_mapping"].startswith("reference camera cam0")
    assert ev["mpjpe_mm"] <= MPJPE_MAX_MM, ev
    assert ev["mpjpe_body_mm"] <= MPJPE_BODY_MAX_MM, ev
    assert ev["pa_mpjpe_mm"] <= ev["mpjpe_mm"] + 1e-6

    # unchanged inputs: the stage is skipped and says so; --force recomputes
    r = cli("fit", ws.root, "--json", "-q")
    assert r.code == 0 and json.loads(r.out)["skipped"] is True


EXACT_HANDS_MAX_MM = 5.0  # issue 20: exact landmarks must not leave the hands off (they were 7.5 mm, 128 on the duo)
EXACT_BODY_MAX_MM = 3.0
# measured: body 0.3 mm, hands 4.3 mm; what is left is fingers seen by one camera only,
# whose bend the two facing views cannot tell from its mirror image


def test_tiny_exact_landmarks_fit_hands(tiny_fit, tmp_path):
    """Exact landmarks (noise 0, no outliers) of the very body that made them: the fit ends
    within a few mm of it, hands included, however small the landmarks' sigma."""
    import shutil
    from pathlib import Path

    from mamma_kit.body.model import load_body_model
    from mamma_kit.cli.app import main
    from mamma_kit.core.smplxfile import SmplxResult
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.fit import evaluate_results
    from mamma_kit.fitting.stages import FitConfig, Fitter
    from mamma_kit.fitting.data import load_fit_data

    ws_dir = tmp_path / "exact"
    top = Path(tiny_fit.root)
    # the rendered capture and its ground truth, not the noisy run's outputs
    shutil.copytree(top, ws_dir, ignore=lambda d, names: [n for n in names if Path(d) == top and
                                                          n in ("smplx", ".cache", "landmarks")])
    try:
        main(["landmarks", str(ws_dir), "--source", "gt", "--noise", "0", "--outliers", "0", "-q"])
    except SystemExit as e:
        assert e.code in (0, None)
    ws = Workspace(ws_dir)
    model = load_body_model("open")
    data = load_fit_data(ws, n_landmarks=len(model.landmark_ids))
    res = Fitter(model, data, FitConfig(stages=3)).fit()
    r = SmplxResult.from_params(res.params(0), res.joints[0], res.frame_times, res.fps, model.name, model.sha256,
                                producer={"reference": data.reference, "person": int(res.person_ids[0])})
    ev = evaluate_results(ws, [r], penetration_frames=None)
    assert ev["mpjpe_body_mm"] <= EXACT_BODY_MAX_MM, ev
    assert ev["mpjpe_hands_mm"] <= EXACT_HANDS_MAX_MM, ev


def test_chunks_as_executor_units_give_fitter_fit(tiny_fit):
    """fit_workspace runs the chunks as units of the executor (fitting/units.py), each reading its
    own frames' landmarks from the files (open_fit_data); the result is Fitter.fit's own on the
    take's data in memory: the same shape fit, chunks and cross-fading."""
    from pathlib import Path

    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.fitting.data import load_fit_data, open_fit_data
    from mamma_kit.fitting.stages import FitConfig, Fitter
    from mamma_kit.fitting.units import fit_chunk_unit, fit_in_units

    model = load_body_model("open")
    ws = Workspace(Path(tiny_fit.root))
    data = load_fit_data(ws, n_landmarks=len(model.landmark_ids))
    cfg = FitConfig(stages=1, chunk=8, overlap=2, shape_frames=6)
    assert len(Fitter(model, data, cfg).plan_chunks(len(data.frame_times))) > 1
    a = Fitter(model, data, cfg).fit()
    unit = Fitter(model, data, cfg)  # the chunks as a worker runs them (Ray): one unit each, joined after
    b = unit.fit(run_chunks=lambda chunks, betas: [fit_chunk_unit(ch, unit, betas) for ch in chunks])
    c = fit_in_units(Fitter(model, open_fit_data(ws, n_landmarks=len(model.landmark_ids)), cfg))
    assert a.chunks == b.chunks == c.chunks
    for key in ("betas", "pose", "transl", "joints", "observed"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
        assert np.array_equal(getattr(a, key), getattr(c, key)), key
