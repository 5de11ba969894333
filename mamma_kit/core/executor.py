"""The one executor interface stages use for independent units of work (DESIGN.md s.7).

``run_units(fn, units, workers)`` calls ``fn(unit)`` for every unit and returns the results
in order. Which engine runs them is process-wide configuration:

- ``local`` (default): in this process when one worker is asked for (or there is one unit,
  or the units are ``threaded``: they already use every core, like network inference), else
  in a local pool of fresh ("spawn") processes - never forked, since a forked child of a
  process that has used torch's OpenMP threads can hang.
- ``ray``: on a Ray cluster (core/executor_ray.py, imported only then): MAMMA_KIT_RAY_ADDRESS
  names a running cluster, else a Ray instance on this machine (127.0.0.1) is started.

The executor is chosen by ``--executor`` (CLI), else MAMMA_KIT_EXECUTOR, else capture.toml's
``[settings] executor``, else local; how many units run side by side by ``--workers``, else
MAMMA_KIT_WORKERS, else one per CPU. ``fn`` and the units must pickle; the unit boundaries are
the caller's, never the engine's, and every process that runs a unit computes deterministically
(core/reproducible.py: a worker is configured like the CLI), so results depend neither on the
executor nor on the number of workers or threads, nor on the order units finish in.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator, Sequence, TypeVar

from mamma_kit.core.errors import UserError

U = TypeVar("U")
R = TypeVar("R")

EXECUTORS = ("local", "ray")
_chosen: dict = {"executor": None, "address": None, "workers": None}  # set by --executor / --workers / a run
# set in a Ray worker process (core/executor_ray.py): the units a unit starts run in its process
INSIDE_UNIT_ENV = "MAMMA_KIT_INSIDE_UNIT"


def default_workers(n_units: int, workers: int | None = None) -> int:
    """Workers for n units: ``workers``, else --workers, else MAMMA_KIT_WORKERS, else one per CPU."""
    if workers is None:
        workers = _chosen["workers"] or configured_workers()
    return max(1, min(int(workers), n_units))


def configured_workers() -> int:
    """MAMMA_KIT_WORKERS, else one per CPU."""
    env = os.environ.get("MAMMA_KIT_WORKERS")
    if env:
        try:
            if int(env) >= 1:
                return int(env)
        except ValueError:
            pass
        raise UserError(f"MAMMA_KIT_WORKERS={env!r} is not a positive whole number", "set it to e.g. 2, or unset it")
    return os.cpu_count() or 1


def set_workers(n: int | None) -> None:
    """Units side by side for this process (``None``: back to MAMMA_KIT_WORKERS / one per CPU)."""
    _chosen["workers"] = None if n is None else max(1, int(n))


# frames per unit for the per-camera stages that can split a video (keypoints, landmarks);
# 0 = the whole camera is one unit
UNIT_FRAMES_ENV = "MAMMA_KIT_UNIT_FRAMES"


def frame_ranges(n_frames: int, unit_frames: int | None = None) -> list[tuple[int, int]]:
    """[start, stop) ranges of at most ``unit_frames`` frames covering n_frames (``None``: the
    MAMMA_KIT_UNIT_FRAMES setting, 0 or unset: one range). The ranges depend only on these two
    numbers, never on the executor, so results are the same on every executor."""
    if unit_frames is None:
        env = os.environ.get(UNIT_FRAMES_ENV, "").strip()
        unit_frames = int(env) if env else 0
    if unit_frames < 0:
        raise UserError(f"--unit-frames {unit_frames} is negative", "pass 0 (a camera per unit) or a frame count")
    if unit_frames == 0 or n_frames <= unit_frames:
        return [(0, n_frames)]
    return [(a, min(a + unit_frames, n_frames)) for a in range(0, n_frames, unit_frames)]


def _check(name: str, where: str) -> str:
    name = str(name).strip().lower()
    if name not in EXECUTORS:
        raise UserError(f"unknown executor '{name}' ({where})", f"use one of {', '.join(EXECUTORS)}")
    return name


def set_executor(name: str | None, address: str | None = None) -> None:
    """Choose the executor for this process (``None``: back to MAMMA_KIT_EXECUTOR / local)."""
    _chosen["executor"] = None if name is None else _check(name, "--executor")
    _chosen["address"] = address


def chosen() -> tuple[str | None, str | None]:
    """(executor, address) as set_executor left them, to restore later with set_executor(*chosen())."""
    return _chosen["executor"], _chosen["address"]


def executor_name() -> str:
    """The executor run_units uses now: set_executor's, else MAMMA_KIT_EXECUTOR, else local."""
    if _chosen["executor"]:
        return _chosen["executor"]
    env = os.environ.get("MAMMA_KIT_EXECUTOR")
    return _check(env, "MAMMA_KIT_EXECUTOR") if env else "local"


def ray_address() -> str | None:
    """The Ray cluster to join (None: start one on this machine)."""
    return _chosen["address"] or os.environ.get("MAMMA_KIT_RAY_ADDRESS") or None


@contextmanager
def executor_for_run(settings: dict) -> Iterator[str]:
    """capture.toml's ``[settings] executor`` / ``ray_address`` for one run, unless --executor
    or MAMMA_KIT_EXECUTOR already chose (the command line and environment win over the file)."""
    saved = dict(_chosen)
    name = settings.get("executor")
    if name is not None and not _chosen["executor"] and not os.environ.get("MAMMA_KIT_EXECUTOR"):
        _chosen["executor"] = _check(name, "capture.toml [settings] executor")
        _chosen["address"] = _chosen["address"] or settings.get("ray_address")
    try:
        yield executor_name()
    finally:
        _chosen.update(saved)


def _init_worker(quiet: bool) -> None:
    # one torch thread per process: the processes already fill the cores (the numbers are the
    # same either way: configure() makes every kernel deterministic)
    from mamma_kit.core.reproducible import configure

    configure()
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover
        pass
    from mamma_kit.core import log

    log.set_quiet(quiet)


def run_units(fn: Callable[[U], R], units: Iterable[U], workers: int | None = None,
              threaded: bool = False) -> list[R]:
    """``[fn(u) for u in units]`` on the chosen executor. ``workers=1`` keeps the units in this
    process whatever the executor (e.g. a model held here); on Ray, ``workers`` caps the units
    in flight. ``threaded``: each unit already uses all cores of a machine, so the local
    executor runs them here one after another (Ray still spreads them over its nodes)."""
    items: Sequence[U] = list(units)
    if os.environ.get(INSIDE_UNIT_ENV):
        return [fn(u) for u in items]
    if len(items) > 1 and workers != 1 and executor_name() == "ray":
        from mamma_kit.core import log
        from mamma_kit.core.executor_ray import run_units_ray

        return run_units_ray(fn, items, workers, address=ray_address(), quiet=log.is_quiet(),
                             cpus=_chosen["workers"] or configured_workers())
    n = 1 if threaded else default_workers(len(items), workers)
    if n <= 1:
        return [fn(u) for u in items]
    import concurrent.futures as cf
    import multiprocessing as mp

    from mamma_kit.core import log

    with cf.ProcessPoolExecutor(n, mp_context=mp.get_context("spawn"), initializer=_init_worker,
                                initargs=(log.is_quiet(),)) as pool:
        return list(pool.map(fn, items))
