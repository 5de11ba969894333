"""Same inputs and settings, same numbers: how the kit computes, and what a result records of it.

A float sum's last bits depend on the order of its terms. Libraries choose that order by how
many threads they split a sum over (torch's and MKL's reductions, oneDNN's convolutions, LAPACK's
factorisations) or by which thread gets there first (torch's ``index_put_(accumulate=True)`` on
the CPU), and a fit magnifies last bits into millimetres where a step is accepted or not. So:

- ``configure()``: torch's deterministic algorithms and single-threaded BLAS under numpy and scipy,
  in every process that computes (the CLI, capture-to-smplx, a local worker, a Ray task; a script
  that calls the stages itself calls it first); an operation with no deterministic form then fails
  loudly instead of varying from run to run.
- ``one_thread()``: a step whose order would follow the thread count runs on one thread (the
  networks' units, the fit's factorisations), so 1, 2 or 64 cores give the same bits. Such
  steps get their speed from units run side by side (core/executor.py), not from threads.
- ``runtime_record()``: what else could change the numbers (library versions, the CPU's vector
  instructions), written into every stage manifest beside the settings.
"""

from __future__ import annotations

import copy
import os
import platform
import sys
from contextlib import contextmanager
from functools import lru_cache
from typing import Iterator

_done: dict[str, bool] = {}


def configure() -> None:
    """Deterministic arithmetic for this process: torch's deterministic kernels, and one thread for
    the OpenBLAS under numpy, scipy and OpenCV (its multi-threaded factorisations and products sum
    in an order that follows the thread count: a board calibration moved in the 8th digit between
    1 and 2 threads). Idempotent; the environment variable reaches libraries loaded later and the
    worker processes started from here."""
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    if _done.get("process"):
        return
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1, user_api="blas")  # the OpenBLAS copies loaded already
    except ImportError:  # pragma: no cover - a dependency
        pass
    # torch costs a process 300 MB and 3 s to import: a stage that never computes with it (match,
    # sync, calibrate) should not pay that, so torch is set up when something first imports it
    if "torch" in sys.modules:
        _deterministic_torch(sys.modules["torch"])
    else:
        sys.meta_path.insert(0, _AfterImport("torch", _deterministic_torch))
    _done["process"] = True


def _deterministic_torch(torch) -> None:
    torch.use_deterministic_algorithms(True)


class _AfterImport:
    """A finder that runs ``then(module)`` once the module ``name`` has been executed (the first
    import of it anywhere), then steps out of the import system."""

    def __init__(self, name: str, then):
        self.name, self.then = name, then

    def find_spec(self, fullname, path=None, target=None):
        if fullname != self.name:
            return None
        import importlib.util

        if self in sys.meta_path:
            sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is not None and spec.loader is not None:
            spec.loader = _ThenLoader(spec.loader, self.then)
        return spec


class _ThenLoader:
    """A module's own loader, with a call after it executes the module (everything else is the
    loader's: resource readers, get_code, ...)."""

    def __init__(self, loader, then):
        self._loader, self._then = loader, then

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        self._loader.exec_module(module)
        self._then(module)

    def __getattr__(self, name):
        return getattr(self._loader, name)


@contextmanager
def one_thread() -> Iterator[None]:
    """torch (and the MKL / LAPACK under it) on one thread inside the block, then as before."""
    import torch

    n = torch.get_num_threads()
    if n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def _version(module: str) -> str | None:
    try:
        from importlib.metadata import version

        return version(module)
    except Exception:
        return None


# the packages whose arithmetic ends up in a result (distribution names)
NUMERIC_PACKAGES = ("numpy", "scipy", "torch", "opencv-contrib-python-headless", "av", "ai-edge-litert", "librosa",
                    "trimesh", "embreex")


def runtime_record() -> dict:
    """Versions and CPU features that can change a result's last bits (not the thread count or
    the executor: they cannot, see the module docstring)."""
    return copy.deepcopy(_runtime_record())


@lru_cache(maxsize=1)
def _runtime_record() -> dict:
    from mamma_kit import __version__

    rec = {"mamma_kit": __version__, "python": platform.python_version(), "machine": platform.machine(),
           "packages": {p: v for p in NUMERIC_PACKAGES if (v := _version(p)) is not None}}
    rec["cpu_vector"] = cpu_vector()
    return rec


def cpu_vector() -> str:
    """The widest vector instructions the CPU offers of those torch, numpy and OpenCV dispatch on
    (their kernels sum in another order on another width), read from /proc/cpuinfo so that a stage
    that does not compute with torch need not import it; ATEN_CPU_CAPABILITY, torch's override, counts."""
    flags: set[str] = set()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith(("flags", "Features")):
                    flags = set(line.split(":", 1)[1].split())
                    break
    except OSError:
        pass
    if {"avx512f", "avx512bw", "avx512vl", "avx512dq"} <= flags:
        width = "avx512"
    elif {"avx2", "fma"} <= flags:
        width = "avx2"
    elif "sve" in flags:
        width = "sve"
    elif "asimd" in flags:
        width = "neon"
    else:
        width = "default"
    override = os.environ.get("ATEN_CPU_CAPABILITY")
    return f"{width} (ATEN_CPU_CAPABILITY={override})" if override else width


def threads_record() -> dict:
    """How this process computed (for the manifest's information; not part of what makes a stage fresh)."""
    out = {"cpus": os.cpu_count()}
    torch = sys.modules.get("torch")  # only where this process computes with it
    if torch is not None:
        out["torch_threads"] = torch.get_num_threads()
        out["deterministic"] = torch.are_deterministic_algorithms_enabled()
    return out
