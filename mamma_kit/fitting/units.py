"""The fit's units of work (DESIGN.md s.7): one chunk of frames of the person set.

The person set is every matched person of the workspace (contact couples them, so they are
fitted together); a unit is one of ``Fitter.plan_chunks``' overlapping frame ranges.
``Fitter.fit`` runs the shape fit (stages 1-2 on frames spread over the sequence) here, hands
the chunks to ``run_chunks`` (below: units of ``core/executor.run_units`` with those betas) and
joins their results (cross-fading the overlaps). So the chunks, their order and their joining
are Fitter.fit's own, whatever the executor.

Every unit runs the very Fitter that ``Fitter.fit`` would: the one built from the whole
sequence (the views it set aside, its point sets), here in this process, or a copy of it
without the sequence's data on a Ray worker, never one rebuilt from a chunk: a chunk's own
consensus of views or its own hands would be another fit.

A unit is a chunk's frame range: it reads only that chunk's data (C cameras x P people x its frames
x L landmarks, Fitter.frames: from the landmark files when the Fitter's data is a FitSource) and
returns its ChunkResult (the chunk's solver State, snapshots, stats, and the views it set aside).
"""

from __future__ import annotations

import copy
from functools import partial

import numpy as np

from mamma_kit.fitting.stages import ChunkResult, Fitter, FitResult


def fit_chunk_unit(chunk: tuple[int, int], fitter: Fitter, betas: np.ndarray | None) -> ChunkResult:
    """One unit: the four stages on one chunk's frames start:stop with the sequence's shape ``betas`` (P, 16)."""
    s, e = chunk
    idx = np.arange(s, e)
    d = fitter.frames(idx)
    r = fitter.fit_chunk(d, betas)
    r.set_aside = tuple(a[:, :, idx].copy() for a in fitter.aside)
    return r


def fit_in_units(fitter: Fitter) -> FitResult:
    """``fitter.fit()`` with its chunks run as units of the executor (see the module docstring). On
    the local executor the chunks run here in order, as Fitter.fit runs them, each joined as it
    ends (a list of every chunk's solver state would grow with the take)."""
    from mamma_kit.core.executor import executor_name, run_units

    if executor_name() != "ray":
        return fitter.fit()
    unit_fitter = copy.copy(fitter)  # its own record of the views set aside (a worker's is sent back)
    unit_fitter.aside = tuple(np.zeros_like(a) for a in fitter.aside)

    def run_chunks(chunks, betas):
        # the chunks use every core through torch: locally they run here in order, as Fitter.fit ran them
        return run_units(partial(fit_chunk_unit, fitter=unit_fitter, betas=betas), chunks, threaded=True)

    return fitter.fit(run_chunks=run_chunks)
