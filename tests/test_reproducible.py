"""Same capture, same result: the numbers depend on the inputs and the settings only.

End to end on a small two-person capture (the demo's recipe with 4 cameras, 12 frames at 480x270):
the pose tracker, BlazePose keypoints, MammaNet landmarks (with the hand and contact networks)
and the four-stage fit with contact, run

- on 1 thread and 1 worker, everything in this process;
- on 2 threads and 2 worker processes, with a CPU hog (two busy processes) beside them;
- on Ray (tasks of 1 thread each, this process on 2 threads);

give identical arrays, bit for bit: no tolerance is needed, because every kernel is
deterministic and no step's sums follow the thread count (core/reproducible.py).
The pieces of that, tested alone: torch's index_put_(accumulate=True) on the CPU (what made the
fit's contact stage vary from run to run) is not used, LAPACK factorisations and MammaNet give
the same bits on 1 and 2 threads, and configure() leaves every BLAS on one thread.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import shutil
from contextlib import contextmanager

import numpy as np
import pytest
import torch

from mamma_kit.core import executor
from mamma_kit.core.reproducible import configure, one_thread


def _spin(stop) -> None:  # pragma: no cover - runs in the hog's processes
    while not stop.is_set():
        pass


@contextmanager
def cpu_hog(n: int = 2):
    """``n`` processes that keep a core each busy until the block ends."""
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    procs = [ctx.Process(target=_spin, args=(stop,), daemon=True) for _ in range(n)]
    for p in procs:
        p.start()
    try:
        yield
    finally:
        stop.set()
        for p in procs:
            p.join(5)
            if p.is_alive():
                p.kill()


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """The rendered capture with its true calibration and clocks (the board session and sync
    are not what this test is about)."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.fit import install_gt_calibration_and_timing
    from mamma_kit.synth.capture import synthesize

    from mamma_kit.core.io import read_toml, write_toml
    from mamma_kit.synth.recipe import find_recipe

    base = tmp_path_factory.mktemp("repro")
    recipe = read_toml(find_recipe("iphone-outdoor-duo"))
    # four of its cameras, whose clocks start together: at this size three leave the second dancer
    # in two views for a frame only, too little for the match to call her a person
    recipe["rig"]["count"] = 4
    recipe["rig"]["clock"].update(offset_s=[0.0, 0.02], audio_start_ms=[0.0, 5.0])
    recipe["audio"]["claps"] = recipe["audio"]["claps"][:1]
    write_toml(base / "duo-small.toml", recipe)
    root = base / "capture"
    synthesize(base / "duo-small.toml", root, frames=5, scale=0.25, board=False)
    install_gt_calibration_and_timing(Workspace(root))
    return root


def _arrays(root) -> dict[str, np.ndarray]:
    """Every numeric array of the workspace's stage outputs (masks, keypoints, landmarks, fits)."""
    out = {}
    for sub in ("masks", "keypoints", "landmarks", "smplx"):
        for f in sorted((root / sub).glob("*.npz")):
            with np.load(f, allow_pickle=False) as d:
                for k in d.files:
                    if d[k].dtype.kind in "biufc":
                        out[f"{f.relative_to(root)}:{k}"] = d[k]
    return out


def _chain(capture, dst, threads: int, workers: int, name: str = "local") -> dict[str, np.ndarray]:
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.fitting.stage import fit_workspace
    from mamma_kit.fitting.stages import FitConfig
    from mamma_kit.keypoints.stage import run_keypoints
    from mamma_kit.landmarks.stage import run_landmarks
    from mamma_kit.masks.stage import run_track
    from mamma_kit.matching.stage import run_match

    shutil.copytree(capture, dst)
    ws = Workspace(dst)
    saved, saved_threads = executor.chosen(), torch.get_num_threads()
    executor.set_executor(name)
    executor.set_workers(workers)
    torch.set_num_threads(threads)
    try:
        run_track(ws, backend="pose", pictures=False, people=2)
        run_keypoints(ws, pictures=False, threads=threads)
        run_landmarks(ws)
        run_match(ws, plots=False)
        # in chunks of 8 overlapping by 4: a shape fit and two chunks, units of the executor
        rep = fit_workspace(ws, config=FitConfig(chunk=8, overlap=4))
    finally:
        executor.set_executor(*saved)
        executor.set_workers(None)
        torch.set_num_threads(saved_threads)
    assert len(rep["persons"]) == 2 and len(rep["chunks"]) >= 2 and rep["stage_stats"].get("stage4"), rep["chunks"]
    return _arrays(dst)


def _assert_identical(a: dict, b: dict, what: str) -> None:
    assert set(a) == set(b), f"{what}: other files or arrays"
    for stage in ("masks/", "keypoints/", "landmarks/", "smplx/"):
        assert any(k.startswith(stage) for k in a), f"{stage} missing"
    differ = [k for k in a if not np.array_equal(a[k], b[k], equal_nan=True)]
    assert not differ, f"{what}: {len(differ)} arrays differ, first {differ[:4]}"


@pytest.mark.slow
def test_threads_workers_executor_and_load_do_not_change_a_number(capture, tmp_path, ray_session):
    one = _chain(capture, tmp_path / "one", threads=1, workers=1)
    with cpu_hog(2):
        two = _chain(capture, tmp_path / "two-busy", threads=2, workers=2)
    _assert_identical(one, two, "1 thread / 1 worker against 2 threads / 2 workers beside a CPU hog")
    on_ray = _chain(capture, tmp_path / "ray", threads=2, workers=2, name="ray")
    _assert_identical(one, on_ray, "local against Ray")


def test_contact_rows_add_in_a_fixed_order():
    """Entries that share a slot of a contact Jacobian row add in index order: run after run,
    on 1 or 2 threads, the same bits (index_put_(accumulate=True) varied in 20 of 20 runs)."""
    from mamma_kit.fitting.contact import point_rows

    class Kin:
        infl = torch.randint(0, 20, (300, 4), generator=torch.Generator().manual_seed(0))

    g = torch.Generator().manual_seed(1)
    k, V = 4000, 3
    u = torch.randn(k, V, 4, 3, generator=g)
    vid = torch.randint(0, 300, (k, V), generator=g)
    coef = torch.randn(k, V, generator=g)
    nrm = torch.nn.functional.normalize(torch.randn(k, 3, generator=g), dim=1)
    pos = torch.arange(21) - 1  # joint j -> active slot j - 1 (joint 0 inactive)
    runs = []
    for threads in (1, 2, 2, 1, 2):
        torch.set_num_threads(threads)
        runs.append(point_rows(Kin(), pos, 3 * 20 + 3, u, vid, coef, nrm))
    assert all(torch.equal(runs[0], r) for r in runs[1:])


def test_factorisations_and_the_networks_are_the_same_on_one_and_two_threads():
    """The fit's batched Cholesky (under one_thread) and a MammaNet and HandNet forward pass
    (their units run on one thread) against what two threads would give."""
    from mamma_kit.fitting.gauss_newton import GaussNewton
    from mamma_kit.landmarks.hands import HAND_IN, load_hand_weights

    g = torch.Generator().manual_seed(0)
    A = torch.randn(40, 168, 190, dtype=torch.float64, generator=g)
    N = A @ A.transpose(1, 2)
    mu = torch.full((40,), 1e-3, dtype=torch.float64)
    facs = []
    for threads in (1, 2):
        torch.set_num_threads(threads)
        facs.append(GaussNewton.damped_cholesky(N, mu))
    assert torch.equal(facs[0], facs[1])
    hand = load_hand_weights().model.eval()
    x = torch.rand(7, 10, HAND_IN, HAND_IN, generator=g) * 255
    side = torch.randint(0, 2, (7,), generator=g)
    outs = []
    for threads in (1, 2):
        torch.set_num_threads(threads)
        with one_thread(), torch.inference_mode():
            outs.append(hand(x, side))
    assert all(torch.equal(outs[0][k], outs[1][k]) for k in outs[0])
    assert torch.get_num_threads() == 2  # one_thread gives the threads back


def test_configure_leaves_every_blas_on_one_thread():
    """numpy's, scipy's and OpenCV's OpenBLAS split their products by thread (a board calibration
    moved in the 8th digit between 1 and 2): configure() holds them to one."""
    import cv2  # noqa: F401 - loads its own OpenBLAS
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_info

    configure()
    blas = [p for p in threadpool_info() if p["user_api"] == "blas"]
    assert blas and all(p["num_threads"] == 1 for p in blas), blas
    assert torch.are_deterministic_algorithms_enabled()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"


def test_torch_imported_after_configure_is_deterministic_and_match_does_not_import_it(tmp_path):
    """configure() sets torch up when something first imports it: a stage that never computes with
    torch (match) does not pay its import, and one that does gets deterministic kernels all the same."""
    import subprocess
    import sys

    code = ("import sys\n"
            "from mamma_kit.core.reproducible import configure, runtime_record\n"
            "configure(); runtime_record()\n"
            "import mamma_kit.matching.stage, mamma_kit.matching.windows, mamma_kit.core.manifest\n"
            "assert 'torch' not in sys.modules, 'torch imported by the match stage'\n"
            "import torch, importlib.resources\n"
            "assert torch.are_deterministic_algorithms_enabled()\n"
            "assert importlib.resources.files('torch').is_dir()\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
