"""What the workspace benchmarks share: a fresh copy of a fitted synthetic capture, refitted.

    from refit import fresh_copy, refit
    ws = fresh_copy(src, dst)          # src without report/, smplx/, .cache/
    m = refit(ws, threads=2)           # fit stages 1-3 (default settings) -> evaluation.fit's metrics
"""

from __future__ import annotations

import shutil
from pathlib import Path


def fresh_copy(src: Path, dst: Path):
    """A Workspace at dst holding src's files but its results (report, smplx, stage caches)."""
    from mamma_kit.core.workspace import Workspace

    src, dst = Path(src), Path(dst)
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst, ignore=lambda d, n: [x for x in n if Path(d) == src and x in
                                                   ("report", "smplx", ".cache")])
    return Workspace(dst)


def refit(ws, threads: int = 2, stages: int = 3, config=None) -> dict:
    """Fit the workspace (``config``, default FitConfig()) and compare the bodies with its ground truth."""
    from mamma_kit.core.smplxfile import read_smplx_result
    from mamma_kit.evaluation.fit import evaluate_results
    from mamma_kit.fitting.stage import fit_workspace
    from mamma_kit.fitting.stages import FitConfig

    fit_workspace(ws, stages=stages, config=config or FitConfig(), threads=threads, force=True)
    return evaluate_results(ws, [read_smplx_result(p) for p in ws.person_files()], penetration_frames=None)
