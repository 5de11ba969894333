"""The fit's units of work (DESIGN.md s.7): one chunk of frames of the person set.

The person set is every matched person of the workspace (contact couples them, so they are
fitted together); a unit is one of ``Fitter.plan_chunks``' overlapping frame ranges. The shape
fit (stages 1-2 on frames spread over the sequence) runs first, here; then the chunks run as
units of ``core/executor.run_units`` with its betas; then ``Fitter.fit`` itself joins them
(cross-fading the overlaps), handed each chunk's result instead of fitting it again. So the
chunks, their order and their joining are Fitter.fit's own, whatever the executor.

A unit reads only its chunk's slice of the fit data (C cameras x P people x its frames x L
landmarks) and returns its ChunkResult (poses (P, T, 55, 3), translations (P, T, 3), ...).
"""

from __future__ import annotations

from functools import partial

import numpy as np

from mamma_kit.fitting.stages import ChunkResult, Fitter, FitResult

_FITTERS: dict = {}  # one Fitter per (model, config, cameras) and process, as Fitter.fit has one


class _ShapeDone(Exception):
    """Stops the first pass of Fitter.fit once the shape fit is done."""


def _key(d, betas, stages) -> tuple:
    return (np.asarray(d.frame_times).tobytes(), None if betas is None else np.asarray(betas).tobytes(), stages)


def _fitter_key(model, cfg, d) -> tuple:
    return (id(model), id(cfg), tuple(d.cameras), bool(d.has_keypoints))


def _fitter_for(model, cfg, d) -> Fitter:
    key = _fitter_key(model, cfg, d)
    if key not in _FITTERS:
        _FITTERS.clear()  # a worker's tasks each bring their own model: keep the last one only
        _FITTERS[key] = (model, cfg, Fitter(model, d, cfg))  # model and cfg kept: their ids stay theirs
    return _FITTERS[key][2]


def fit_chunk_unit(chunk_data, model, cfg, betas: np.ndarray) -> ChunkResult:
    """One unit: the four stages on one chunk's data with the sequence's shape ``betas`` (P, 16)."""
    return _fitter_for(model, cfg, chunk_data).fit_chunk(chunk_data, betas)


def fit_in_units(fitter: Fitter) -> FitResult:
    """``fitter.fit()`` with its chunks run as units of the executor (see the module docstring)."""
    from mamma_kit.core.executor import run_units

    d = fitter.data
    chunks = fitter.plan_chunks(len(d.frame_times))
    if len(chunks) <= 1:  # one chunk: nothing to spread (and it fits its own shape)
        return fitter.fit()
    fit_chunk = fitter.fit_chunk
    done: dict = {}

    def shape_only(dd, betas=None, stages=None):
        done[_key(dd, betas, stages)] = r = fit_chunk(dd, betas, stages)
        raise _ShapeDone(r)

    fitter.fit_chunk = shape_only  # the instance's own: Fitter.fit picks its shape frames itself
    try:
        return fitter.fit()  # (only if it fitted no chunk)
    except _ShapeDone as e:
        betas = e.args[0].betas
    finally:
        del fitter.fit_chunk
    _FITTERS.clear()
    # units run here use this very fitter, as Fitter.fit would; a worker builds its own
    _FITTERS[_fitter_key(fitter.model, fitter.cfg, d)] = (fitter.model, fitter.cfg, fitter)
    parts = [d.slice_frames(slice(s, e)) for s, e in chunks]
    # the chunks use every core through torch: locally they run here in order, as Fitter.fit ran them
    results = run_units(partial(fit_chunk_unit, model=fitter.model, cfg=fitter.cfg, betas=betas), parts,
                        threaded=True)
    _FITTERS.clear()
    done.update({_key(p, betas, None): r for p, r in zip(parts, results)})

    def precomputed(dd, betas=None, stages=None):
        r = done.get(_key(dd, betas, stages))
        return r if r is not None else fit_chunk(dd, betas, stages)

    fitter.fit_chunk = precomputed
    try:
        return fitter.fit()
    finally:
        del fitter.fit_chunk
