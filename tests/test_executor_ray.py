"""run_units on Ray (issue 25): a Ray instance on the loopback address of this machine runs the
units; results equal the local executor's, what units share goes to the object store once, a
UserError raised in a unit comes back unchanged, and a unit that fails is retried once and then
named in one UserError. End to end: synth + track + landmarks + fit of the tiny recipe through
Ray give the same files as the local executor.
"""

from __future__ import annotations

import os
import sys
from functools import partial

import numpy as np
import pytest

os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # before ray's import: listen on 127.0.0.1 only
ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'mamma-kit[ray]')")

from mamma_kit.core import executor  # noqa: E402
from mamma_kit.core.errors import UserError  # noqa: E402


@pytest.fixture(scope="module")
def ray_local():
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    # the units below are this test module's functions: send them by value, the workers
    # cannot import tests/
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    if not ray.is_initialized():
        ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="warning")
    assert ray.util.get_node_ip_address() == "127.0.0.1"
    executor.set_executor("ray")
    yield ray
    executor.set_executor(None)
    ray.shutdown()


def _scaled_sum(unit, table_n3):
    k, offset = unit
    return float(table_n3[k].sum()) + offset


def _shared_first(unit):
    table_n3, k = unit
    return float(table_n3[k].sum())


def _bad_input(unit):
    if unit == "cam1":
        raise UserError("masks/cam1.npz is 10x10 but cam1.mp4 is 20x20", "run `mamma-kit track` again")
    return unit


def _fails_once(unit, marks):
    """Fails the first time it runs a unit (a mark file says it ran), then works."""
    mark = marks / f"{unit}.tried"
    if not mark.exists():
        mark.write_text("1")
        raise RuntimeError("worker hiccup")
    return unit * 2


def _always_fails(unit):
    if unit == 2:
        raise ValueError("frame 17 has no image")
    return unit


def test_results_equal_local_and_shared_objects_go_once(ray_local):
    from mamma_kit.core.executor_ray import shared_elements

    table_n3 = np.arange(30.0).reshape(10, 3)
    units = [(k, 0.5 * k) for k in range(6)]
    fn = partial(_scaled_sum, table_n3=table_n3)
    with_ray = executor.run_units(fn, units)
    executor.set_executor("local")
    try:
        local = executor.run_units(fn, units, workers=1)
    finally:
        executor.set_executor("ray")
    assert with_ray == local
    # the same array in every tuple unit is put once and handed to each task
    shared_units = [(table_n3, k) for k in range(4)]
    assert list(shared_elements(shared_units)) == [id(table_n3)]
    assert executor.run_units(_shared_first, shared_units) == [float(table_n3[k].sum()) for k in range(4)]


def test_user_error_in_a_unit_comes_back_unchanged(ray_local):
    want = UserError("masks/cam1.npz is 10x10 but cam1.mp4 is 20x20", "run `mamma-kit track` again")
    with pytest.raises(UserError) as e:
        executor.run_units(_bad_input, ["cam0", "cam1", "cam2"])
    assert e.value.line() == want.line() and e.value.hint == want.hint


def test_failed_unit_is_retried_then_named(ray_local, tmp_path):
    assert executor.run_units(partial(_fails_once, marks=tmp_path), [1, 2, 3]) == [2, 4, 6]
    with pytest.raises(UserError) as e:
        executor.run_units(_always_fails, [0, 1, 2, 3])
    line = e.value.line()
    assert "unit #3 (3 of 4)" in line and "tried 2 times" in line and "frame 17 has no image" in line, line


def test_executor_settings(monkeypatch):
    saved = executor.chosen()
    try:
        executor.set_executor(None)
        monkeypatch.delenv("MAMMA_KIT_EXECUTOR", raising=False)
        with pytest.raises(UserError):
            executor.set_executor("dask")
        with executor.executor_for_run({"executor": "ray"}) as name:  # capture.toml's choice
            assert name == "ray"
        assert executor.executor_name() == "local"
        monkeypatch.setenv("MAMMA_KIT_EXECUTOR", "local")  # the environment wins over the file
        with executor.executor_for_run({"executor": "ray"}) as name:
            assert name == "local"
        executor.set_executor("ray")  # and --executor over both
        monkeypatch.setenv("MAMMA_KIT_EXECUTOR", "local")
        assert executor.executor_name() == "ray"
    finally:
        executor.set_executor(*saved)


def _arrays(root) -> dict[str, np.ndarray]:
    """Every numeric array of the workspace's .npz files (masks, landmarks, fits, ground truth)."""
    out = {}
    for f in sorted(root.rglob("*.npz")):
        if ".cache" in f.parts:
            continue
        with np.load(f, allow_pickle=False) as d:
            for k in d.files:
                if d[k].dtype.kind in "biufc":
                    out[f"{f.relative_to(root)}:{k}"] = d[k]
    return out


def _tiny_chain(root, name: str, monkeypatch) -> dict:
    """synth + track + landmarks (noisy ground truth) + fit (stages 1-2, two chunks) on one executor;
    the local one with one worker, in this process (the same units in the same order)."""
    import torch

    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.fit import install_gt_calibration_and_timing
    from mamma_kit.fitting.stage import fit_workspace
    from mamma_kit.fitting.stages import FitConfig
    from mamma_kit.landmarks.stage import run_landmarks
    from mamma_kit.masks.stage import run_track
    from mamma_kit.synth.capture import synthesize

    saved, threads = executor.chosen(), torch.get_num_threads()
    executor.set_executor(name)
    monkeypatch.setenv("MAMMA_KIT_WORKERS", "1" if name == "local" else "2")
    torch.set_num_threads(1)  # as in a worker: the fit's sums in the same order on both executors
    try:
        synthesize("tiny", root, board=False)
        ws = Workspace(root)
        install_gt_calibration_and_timing(ws)
        run_track(ws, backend="gt", pictures=False)
        run_landmarks(ws, source="gt", noise="1.2%", outliers=0.05, seed=0)
        # 15 frames in chunks of 12 with overlap 4: a shape fit and two chunks cross-faded
        rep = fit_workspace(ws, stages=2, config=FitConfig(chunk=12, overlap=4))
    finally:
        executor.set_executor(*saved)
        torch.set_num_threads(threads)
    assert len(rep["chunks"]) == 2, rep["chunks"]
    return _arrays(root)


@pytest.mark.slow
def test_tiny_chain_on_ray_equals_local(ray_local, tmp_path, monkeypatch):
    local = _tiny_chain(tmp_path / "local", "local", monkeypatch)
    on_ray = _tiny_chain(tmp_path / "ray", "ray", monkeypatch)
    assert set(local) == set(on_ray) and any(k.startswith("smplx/") for k in local)
    assert any(k.startswith("masks/") for k in local) and any(k.startswith("landmarks/") for k in local)
    for k in local:
        assert np.array_equal(local[k], on_ray[k], equal_nan=True), k


def test_cli_executor_option(cli, tmp_path):
    saved = executor.chosen()
    try:
        r = cli("--executor", "dask", "fit", tmp_path)
        assert r.code == 2 and "unknown executor 'dask'" in r.err, r
        r = cli("--executor", "ray", "fit", tmp_path / "missing")  # chosen before the command runs
        assert r.code == 2 and executor.executor_name() == "ray", r
    finally:
        executor.set_executor(*saved)
