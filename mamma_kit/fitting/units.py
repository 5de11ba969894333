"""The fit's units of work (DESIGN.md s.7): one chunk of frames of the person set.

The person set is every matched person of the workspace (contact couples them, so they are
fitted together); a unit is one of ``Fitter.plan_chunks``' overlapping frame ranges.
``Fitter.fit`` runs the shape fit (stages 1-2 on frames spread over the sequence) here, hands
the chunks to ``run_chunks`` (below: units of ``core/executor.run_units`` with those betas) and
joins their results (cross-fading the overlaps). So the chunks, their order and their joining
are Fitter.fit's own, whatever the executor.

A unit reads only its chunk's slice of the fit data (C cameras x P people x its frames x L
landmarks) and returns its ChunkResult (the chunk's solver State, snapshots, stats).
"""

from __future__ import annotations

from functools import partial

import numpy as np

from mamma_kit.fitting.stages import ChunkResult, Fitter, FitResult

_FITTERS: dict = {}  # one Fitter per (model, config, cameras) and process, as Fitter.fit has one


def _fitter_key(model, cfg, d) -> tuple:
    return (id(model), id(cfg), tuple(d.cameras), bool(d.has_keypoints))


def _fitter_for(model, cfg, d) -> Fitter:
    key = _fitter_key(model, cfg, d)
    if key not in _FITTERS:
        _FITTERS.clear()  # a worker's tasks each bring their own model: keep the last one only
        _FITTERS[key] = (model, cfg, Fitter(model, d, cfg))  # model and cfg kept: their ids stay theirs
    return _FITTERS[key][2]


def fit_chunk_unit(chunk_data, model, cfg, betas: np.ndarray | None) -> ChunkResult:
    """One unit: the four stages on one chunk's data with the sequence's shape ``betas`` (P, 16)."""
    return _fitter_for(model, cfg, chunk_data).fit_chunk(chunk_data, betas)


def fit_in_units(fitter: Fitter) -> FitResult:
    """``fitter.fit()`` with its chunks run as units of the executor (see the module docstring)."""
    from mamma_kit.core.executor import run_units

    def run_chunks(parts, betas):
        _FITTERS.clear()
        # units run here use this very fitter, as Fitter.fit would; a worker builds its own
        _FITTERS[_fitter_key(fitter.model, fitter.cfg, fitter.data)] = (fitter.model, fitter.cfg, fitter)
        try:
            # the chunks use every core through torch: locally they run here in order, as Fitter.fit ran them
            return run_units(partial(fit_chunk_unit, model=fitter.model, cfg=fitter.cfg, betas=betas), parts,
                             threaded=True)
        finally:
            _FITTERS.clear()

    return fitter.fit(run_chunks=run_chunks)
