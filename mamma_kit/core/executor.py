"""The one executor interface stages use for independent units of work (DESIGN.md s.7).

``run_units(fn, units, workers)`` calls ``fn(unit)`` for every unit and returns the results
in order: in this process when one worker is asked for (or there is one unit), else in a
local pool of fresh ("spawn") processes - never forked, since a forked child of a process
that has used torch's OpenMP threads can hang. ``fn`` and the units must pickle. A
distributed engine (Ray, Dask) can stand in for the pool behind the same call.
"""

from __future__ import annotations

import os
from typing import Callable, Iterable, Sequence, TypeVar

U = TypeVar("U")
R = TypeVar("R")


def default_workers(n_units: int, workers: int | None = None) -> int:
    """Workers for n units: ``workers``, else MAMMA_KIT_WORKERS, else one per CPU."""
    if workers is None:
        env = os.environ.get("MAMMA_KIT_WORKERS")
        workers = int(env) if env else (os.cpu_count() or 1)
    return max(1, min(int(workers), n_units))


def _init_worker(quiet: bool) -> None:
    # one torch thread per process: the processes already fill the cores
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover
        pass
    from mamma_kit.core import log

    log.set_quiet(quiet)


def run_units(fn: Callable[[U], R], units: Iterable[U], workers: int | None = None) -> list[R]:
    items: Sequence[U] = list(units)
    n = default_workers(len(items), workers)
    if n <= 1:
        return [fn(u) for u in items]
    import concurrent.futures as cf
    import multiprocessing as mp

    from mamma_kit.core import log

    with cf.ProcessPoolExecutor(n, mp_context=mp.get_context("spawn"), initializer=_init_worker,
                                initargs=(log.is_quiet(),)) as pool:
        return list(pool.map(fn, items))
