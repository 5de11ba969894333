from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings as hypothesis_settings

from mamma_kit.core.camera import Camera, Rig, rodrigues
from mamma_kit.core.reproducible import configure
from mamma_kit.core.tracks import LandmarkTracks

# the tests compute as the CLI does: deterministic kernels, one BLAS thread (an operation with
# no deterministic form fails here first)
configure()

# property tests draw the same examples on every run: a red run then says the code changed, not
# that a new draw was unlucky (GCC-PHAT once drew delay -7.0 with noise seed 158: 0.27 samples off)
hypothesis_settings.register_profile("repeatable", derandomize=True)
hypothesis_settings.load_profile("repeatable")


class CliResult:
    def __init__(self, code: int, out: str, err: str):
        self.code, self.out, self.err = code, out, err

    def __repr__(self) -> str:
        return f"CliResult(code={self.code}, out={self.out[-500:]!r}, err={self.err[-500:]!r})"


@pytest.fixture
def cli(capsys):
    """Run `mamma-kit ARGS` in-process; return exit code, stdout, stderr."""
    from mamma_kit.cli.app import main

    def run(*args: str) -> CliResult:
        capsys.readouterr()
        code = 0
        try:
            main([str(a) for a in args])
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        cap = capsys.readouterr()
        return CliResult(code, cap.out, cap.err)

    return run


def make_ring_rig(n: int = 4, radius: float = 4.5, height: float = 1.6, size=(640, 480), f: float = 600.0,
                  dist=None, model: str = "radtan", seed: int = 0) -> Rig:
    """Cameras on a ring looking at (0, 0, 1) with world Z up."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        C = np.array([radius * np.cos(a), radius * np.sin(a), height])
        target = np.array([0, 0, 1.0])
        z = target - C
        z /= np.linalg.norm(z)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        K = np.array([[f * (1 + 0.01 * rng.standard_normal()), 0, size[0] / 2 - 0.5 + rng.uniform(-5, 5)],
                      [0, f, size[1] / 2 - 0.5 + rng.uniform(-5, 5)], [0, 0, 1]])
        d = np.zeros(5) if dist is None else np.asarray(dist, float)
        cams.append(Camera(f"cam{i}", size, K, d, model, R, -R @ C))
    return Rig(cams)


def walking_people(rng, P, T, L=40):
    """3D points of P people over T frames: (T, P, L, 3), bodies ~1.7 m tall walking apart."""
    base = rng.uniform(-1.5, 1.5, (P, 2))
    vel = rng.normal(0, 0.03, (P, 2))
    body = np.c_[rng.normal(0, 0.15, (L, 2)), rng.uniform(0.0, 1.7, L)]
    X = np.zeros((T, P, L, 3))
    for t in range(T):
        X[t, :, :, :2] = base[:, None] + t * vel[:, None] + body[None, :, :2]
        X[t, :, :, 2] = body[None, :, 2]
    return X


def landmark_view(cam, X, times, perm=None, noise=0.0, rng=None):
    """LandmarkTracks of `cam` seeing X (T, P, L, 3): track j is person perm[j], all visible,
    with Gaussian pixel noise of sd `noise` drawn from `rng`."""
    T, P, L, _ = X.shape
    perm = np.arange(P) if perm is None else perm
    xy = cam.project(X[:, perm])
    if noise:
        xy = xy + rng.normal(0, noise, xy.shape)
    lt = LandmarkTracks.empty(cam.name, cam.size, times, np.arange(P), L)
    lt.xy[:] = xy
    lt.visibility[:] = 1.0
    lt.valid[:] = True
    return lt


@pytest.fixture
def ring_rig() -> Rig:
    return make_ring_rig()


@pytest.fixture(scope="session")
def ray_session():
    """One Ray instance on this machine's loopback address for the whole session (starting one
    costs seconds); skipped where ray is not installed."""
    import os

    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # before ray's import: 127.0.0.1 only
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'mamma-kit[ray]')")
    if not ray.is_initialized():
        ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="warning")
    assert ray.util.get_node_ip_address() == "127.0.0.1"
    yield ray
    ray.shutdown()
