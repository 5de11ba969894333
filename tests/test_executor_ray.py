"""run_units on Ray (issue 25): a Ray instance on the loopback address of this machine runs the
units; results equal the local executor's, what units share goes to the object store once, a
UserError raised in a unit comes back unchanged, and a unit that fails is retried once and then
named in one UserError. (End to end, Ray against the local executor: tests/test_reproducible.py.)
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


# the units below are this test module's functions: send them by value, the workers cannot
# import tests/
ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])


@pytest.fixture(scope="module")
def ray_local(ray_session):
    """Ray (conftest's instance on 127.0.0.1) as this module's executor."""
    executor.set_executor("ray")
    yield ray
    executor.set_executor(None)


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


def test_cli_executor_option(cli, tmp_path):
    saved = executor.chosen()
    try:
        r = cli("--executor", "dask", "fit", tmp_path)
        assert r.code == 2 and "unknown executor 'dask'" in r.err, r
        r = cli("--executor", "ray", "fit", tmp_path / "missing")  # chosen before the command runs
        assert r.code == 2 and executor.executor_name() == "ray", r
    finally:
        executor.set_executor(*saved)
