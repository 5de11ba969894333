"""run_units on Ray (imported only when the ray executor is chosen; ``pip install mamma-kit[ray]``).

Each unit is one Ray task, retried once (a lost worker or node, or an exception), then named in
one UserError. What the units share is put in Ray's object store once, not pickled per task: the
function (with a functools.partial's arguments) and every element of tuple units that is the very
same object in more than one unit (a synthetic scene, a rig). A UserError raised inside a unit
comes back unchanged (its message and hint), so bad input still ends in one line and exit code 2.
Results are returned in the units' order; progress advances as units finish. Shared objects
travel as pickled bytes, so each unit unpickles its own writable copy, as with the local pool
(Ray's zero-copy arrays are read-only, and some units write to what they are given).
"""

from __future__ import annotations

import os
import pickle
from functools import partial
from pathlib import Path
from typing import Any, Callable, Sequence

from mamma_kit.core import log
from mamma_kit.core.errors import UserError

INSIDE_UNIT_ENV = "MAMMA_KIT_INSIDE_UNIT"  # read by core/executor.py's run_units
RETRIES = 1  # one more try for a unit that failed (its worker died, or it raised)
_SMALL = (str, bytes, int, float, bool, type(None), Path)  # cheap to send with every task
_remote: dict[str, Any] = {}


class _Slot:
    """Stands in a unit's tuple for the shared object passed as the task's ``i``-th extra argument."""

    def __init__(self, i: int):
        self.i = i


def loopback_only() -> None:
    """Make a Ray instance started by this process listen on 127.0.0.1 only (read when ray is
    first imported: Ray's single-machine mode takes the loopback address as the node's)."""
    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")


def _init_ray(address: str | None, cpus: int | None = None):
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if not address:
        loopback_only()
    try:
        import ray
    except ImportError:
        raise UserError("the ray executor needs the ray package, which is not installed",
                        "pip install 'mamma-kit[ray]', or use --executor local") from None
    if not ray.is_initialized():
        if address:  # a running cluster: every node needs this mamma-kit installed
            ray.init(address=address, logging_level="warning")
        else:  # a Ray instance on this machine, without a dashboard, with the CPUs given
            ray.init(address="local", num_cpus=cpus, include_dashboard=False, logging_level="warning")
    if "task" not in _remote:
        _remote["task"] = ray.remote(_run_one)
    return ray


def _run_one(quiet: bool, fn_bytes: bytes, template: Any, *shared_bytes: bytes) -> tuple:
    """One unit in a Ray worker: ("ok", result) or ("user-error", message, hint)."""
    os.environ[INSIDE_UNIT_ENV] = "1"  # units this unit starts run here, in order
    from mamma_kit.core.reproducible import configure

    configure()  # the same kernels as in the CLI's process: the same numbers on every node
    try:  # one torch thread per task, as in the local pool: the tasks fill the cores
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover
        pass
    log.set_quiet(quiet)
    fn = pickle.loads(fn_bytes)
    shared = [pickle.loads(b) for b in shared_bytes]
    unit = type(template)(shared[x.i] if isinstance(x, _Slot) else x for x in template) \
        if isinstance(template, (tuple, list)) else template
    try:
        return ("ok", fn(unit))
    except UserError as e:  # bad input: not retried, and reported as it was raised
        return ("user-error", e.message, e.hint)


def shared_elements(items: Sequence) -> dict[int, Any]:
    """id -> object for the tuple elements that appear (the same object) in more than one unit."""
    seen: dict[int, int] = {}
    objs: dict[int, Any] = {}
    for u in items:
        if isinstance(u, (tuple, list)):
            for x in u:
                if not isinstance(x, _SMALL):
                    seen[id(x)] = seen.get(id(x), 0) + 1
                    objs[id(x)] = x
    return {k: objs[k] for k, c in seen.items() if c > 1}


def describe_unit(unit: Any, i: int) -> str:
    """A short name for a unit: its camera name or first text / path element, else its number."""
    first = unit
    if isinstance(unit, (tuple, list)):
        first = next((x for x in unit if isinstance(x, (str, Path))), None)
    if isinstance(first, Path):
        return first.name
    if isinstance(first, str):
        return first
    name = getattr(unit, "name", None)
    return str(name) if isinstance(name, str) else f"#{i + 1}"


def _label(fn: Callable) -> str:
    f = fn.func if isinstance(fn, partial) else fn
    return str(getattr(f, "__name__", type(f).__name__)).strip("_").replace("_", " ")


def run_units_ray(fn: Callable, items: Sequence, workers: int | None = None, address: str | None = None,
                  quiet: bool = False, cpus: int | None = None) -> list:
    """``[fn(u) for u in items]`` as Ray tasks, at most ``workers`` in flight (None: all), on the
    cluster at ``address`` (None: a Ray instance on this machine with ``cpus`` CPUs, started if
    none runs)."""
    ray = _init_ray(address, cpus)
    from ray.exceptions import RayError

    task = _remote["task"].options(max_retries=RETRIES, retry_exceptions=True)
    dumps = ray.cloudpickle.dumps
    fn_ref = ray.put(dumps(fn))
    shared = shared_elements(items)
    refs = {k: ray.put(dumps(v)) for k, v in shared.items()}
    order = list(refs)
    slots = {k: _Slot(j) for j, k in enumerate(order)}
    shared_refs = [refs[k] for k in order]

    def submit(u):
        template = type(u)(slots.get(id(x), x) if id(x) in shared else x for x in u) \
            if isinstance(u, (tuple, list)) and shared else u
        return task.remote(quiet, fn_ref, template, *shared_refs)

    n = len(items)
    cap = n if not workers else max(1, int(workers))
    results: list = [None] * n
    pending: dict = {}
    nxt = 0
    label = _label(fn)
    try:
        with log.progress(f"{label} (ray)", n) as advance:
            while nxt < n or pending:
                while nxt < n and len(pending) < cap:
                    pending[submit(items[nxt])] = nxt
                    nxt += 1
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    i = pending.pop(ref)
                    try:
                        out = ray.get(ref)
                    except RayError as e:
                        cause = getattr(e, "cause", None) or e
                        why = str(cause).strip().splitlines()
                        raise UserError(
                            f"unit {describe_unit(items[i], i)} ({i + 1} of {n}) of {label} failed on Ray "
                            f"(tried {RETRIES + 1} times): {type(cause).__name__}: {why[0] if why else ''}",
                            "its traceback is in the Ray worker's log above; run it with --executor local "
                            "to see it in this process") from None
                    if out[0] == "user-error":
                        raise UserError(out[1], out[2])
                    results[i] = out[1]
                    advance()
    finally:
        for ref in pending:  # a failure or Ctrl-C: stop what is still queued or running
            ray.cancel(ref)
    return results
