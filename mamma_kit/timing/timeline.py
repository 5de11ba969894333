"""Which frame of each camera shows a given reference time, and how far off it is.

Frame times are the frames' own presentation timestamps (phones record variable frame
rate), mapped to the reference clock by each camera's clock model. For every reference time
the nearest frame is chosen; its residual t_ref - to_ref(t_frame) (seconds, reference clock;
positive = the frame was taken before t_ref) is kept so later stages can interpolate.

timing_timeline.npz (written by ``mamma-kit sync`` beside timing.toml)::

    t_ref_s         (T,)   float64  reference times: the reference camera's frames
    cameras         (C,)   str      camera names, in capture order
    frame_index_ct  (C, T) int64    nearest frame of each camera, -1 outside its recording
    residual_s_ct   (C, T) float64  t_ref - frame time on the reference clock (NaN where -1)
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.io import read_npz, write_npz


def timeline(clocks: Mapping[str, ClockModel], frame_times: Mapping[str, np.ndarray], t_ref
             ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per camera: (frame index (T,) int64, -1 when t_ref is outside the recording; residual (T,)
    float64 seconds on the reference clock)."""
    t = np.atleast_1d(np.asarray(t_ref, np.float64))
    out = {}
    for name, clk in clocks.items():
        ts = np.asarray(frame_times[name], np.float64)
        tr = clk.to_ref(ts)  # frames on the reference clock (monotonic)
        j = np.clip(np.searchsorted(tr, t), 1, max(len(tr) - 1, 1))
        if len(tr) == 1:
            idx = np.zeros(len(t), np.int64)
        else:
            idx = np.where(np.abs(t - tr[j - 1]) <= np.abs(tr[j] - t), j - 1, j).astype(np.int64)
        res = t - tr[idx]
        dt = np.diff(tr)
        half_first = 0.5 * (dt[0] if len(dt) else 0.0)
        half_last = 0.5 * (dt[-1] if len(dt) else 0.0)
        outside = (t < tr[0] - half_first) | (t > tr[-1] + half_last)
        idx[outside] = -1
        res[outside] = np.nan
        out[name] = (idx, res)
    return out


def write_timeline(path: str | Path, clocks: Mapping[str, ClockModel], frame_times: Mapping[str, np.ndarray],
                   reference: str) -> Path:
    t_ref = clocks[reference].to_ref(np.asarray(frame_times[reference], np.float64))
    tl = timeline(clocks, frame_times, t_ref)
    names = list(clocks)
    return write_npz(path, t_ref_s=t_ref, cameras=np.array(names),
                     frame_index_ct=np.stack([tl[n][0] for n in names]),
                     residual_s_ct=np.stack([tl[n][1] for n in names]))


def read_timeline(path: str | Path) -> dict[str, np.ndarray]:
    return read_npz(path, "timeline")
