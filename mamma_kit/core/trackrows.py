"""Keypoint and landmark files as rows: only the person-frames there are, written and read a window
of frames at a time.

A take of minutes has thousands of frames and, as people leave, come back and are lost behind
others, dozens to hundreds of tracks per view: a frames x tracks grid of 512 landmarks per cell is
mostly empty, and grows with both. On disk a track file therefore holds one row per (frame, track)
a stage looked at, sorted by frame, then track column:

    camera, image_size, frame_times (T,), track_ids (K,), strings, producer   the take's index
    row_frame (N,) int32, row_track (N,) int32                                 each row's frame, column
    valid (N,) and every other per-cell array with N rows: xy (N, L, 2), ...

In memory the tracks types (core.tracks) stay frames x tracks arrays, of a window of frames (or of a
short take). ``RowWriter`` writes rows as a stage makes them (each array streams into a temporary
file beside the output; ``close`` assembles the .npz), so a stage's memory follows its window, not
the take; ``TrackFile`` reads a window of frames (rows streamed from the zip members, only the
rows asked for kept). Files in the older frames x tracks layout read the same way.

A tracks type describes its cells with ``cell_spec(n) -> {name: (shape after (T, K), dtype, fill)}``
(``fill``: an empty cell's value) and ``n_points`` (n for its spec).
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import NpzRows, atomic_path, read_npz, temp_beside

ROW_KEYS = ("row_frame", "row_track")
_COPY_BLOCK = 16 << 20  # bytes per read when a temporary array file is copied into the zip


def cell_names(cls, n: int) -> list[str]:
    return list(cls.cell_spec(n))


def header_names(cls) -> list[str]:
    """The tracks type's fields that are not per cell (camera, image_size, frame_times, track_ids,
    its strings, producer)."""
    cells = set(cls.cell_spec(1))
    return [f.name for f in fields(cls) if f.name not in cells]


def _header_arrays(cls, values: dict) -> dict[str, np.ndarray]:
    out = {}
    for name in header_names(cls):
        v = values.get(name, "")
        if name == "producer":
            out[name] = np.array(json.dumps(v or {}))
        elif name == "image_size":
            out[name] = np.asarray(v, np.int64)
        elif name == "frame_times":
            out[name] = np.asarray(v, np.float64)
        elif name == "track_ids":
            out[name] = np.asarray(v, np.int64)
        else:
            out[name] = np.array(v)
    return out


def _header_values(cls, d: dict, path) -> dict[str, Any]:
    out = {}
    for name in header_names(cls):
        if name == "producer":
            out[name] = json.loads(str(d.get("producer", "{}")))
        elif name == "image_size":
            out[name] = tuple(int(v) for v in d["image_size"])
        elif name == "frame_times":
            out[name] = np.asarray(d["frame_times"], np.float64)
        elif name == "track_ids":
            out[name] = np.asarray(d["track_ids"], np.int64)
        elif name == "camera":
            out[name] = str(d.get("camera", Path(path).stem))
        elif name in d:
            out[name] = str(d[name])
    return out


def empty_cells(spec: dict, T: int, K: int) -> dict[str, np.ndarray]:
    return {name: np.full((T, K, *shape), fill, dtype) for name, (shape, dtype, fill) in spec.items()}


def _is_fill(a: np.ndarray, fill) -> np.ndarray:
    """(N, W) -> (N,): every value of the row equals ``fill`` (NaN equals NaN)."""
    same = np.isnan(a) if isinstance(fill, float) and np.isnan(fill) else a == fill
    return same.all(1)


def occupied(tracks) -> np.ndarray:
    """(T, K) bool: the cells a file must keep (valid, or any value other than an empty cell's)."""
    spec = tracks.cell_spec(tracks.n_points)
    T, K = len(tracks.frame_times), len(tracks.track_ids)
    keep = np.zeros((T, K), bool)
    for name, (shape, _, fill) in spec.items():
        a = getattr(tracks, name).reshape(T * K, int(np.prod(shape)))  # explicit width: T * K may be 0
        keep |= ~_is_fill(a, fill).reshape(T, K)
    return keep


def save_rows(tracks, path: str | os.PathLike) -> Path:
    """A frames x tracks object written as rows (its occupied cells)."""
    from mamma_kit.core.io import write_npz

    spec = tracks.cell_spec(tracks.n_points)
    t_n, k_n = np.nonzero(occupied(tracks))
    cells = {name: np.ascontiguousarray(getattr(tracks, name)[t_n, k_n], dtype=dtype)
             for name, (_, dtype, _) in spec.items()}
    return write_npz(path, **_header_arrays(type(tracks), vars(tracks)), row_frame=t_n.astype(np.int32), row_track=k_n.astype(np.int32),
                     **cells)


class RowWriter:
    """Rows of one camera's tracks written as they are made, in frame order (see module doc).

    >>> w = RowWriter(path, LandmarkTracks, header)   # header: the type's non-cell fields
    >>> w.append(frame_n, track_n, xy=..., valid=...)  # fields left out are an empty cell's
    >>> w.close()                                      # -> path (atomic)

    Rows must come sorted by (frame, track column); ``abort`` (or an exception inside ``with``)
    removes the temporary files."""

    def __init__(self, path: str | os.PathLike, cls, header: dict, n: int):
        self.path, self.cls, self.n = Path(path), cls, int(n)
        self.header = header
        self.spec = cls.cell_spec(self.n)
        self.n_rows = 0
        self._last = (-1, -1)
        self._files: dict[str, tuple[Path, Any]] = {}
        for name in (*ROW_KEYS, *self.spec):
            tmp = temp_beside(self.path, f".{name}.raw")
            self._files[name] = (tmp, open(tmp, "wb"))

    def _dtype(self, name: str) -> np.dtype:
        return np.dtype(np.int32) if name in ROW_KEYS else np.dtype(self.spec[name][1])

    def _shape(self, name: str) -> tuple[int, ...]:
        return () if name in ROW_KEYS else tuple(self.spec[name][0])

    def append(self, frame_n, track_n, **cells: np.ndarray) -> None:
        frame_n = np.asarray(frame_n, np.int64).reshape(-1)
        track_n = np.asarray(track_n, np.int64).reshape(-1)
        n = len(frame_n)
        if n == 0:
            return
        unknown = set(cells) - set(self.spec)
        if unknown:
            raise ValueError(f"RowWriter: {self.cls.__name__} has no cell field {', '.join(sorted(unknown))}")
        key = frame_n * (1 << 32) + track_n
        if np.any(np.diff(key) <= 0) or (frame_n[0], track_n[0]) <= self._last:
            raise ValueError("RowWriter: rows must come sorted by (frame, track column), each once")
        self._last = (int(frame_n[-1]), int(track_n[-1]))
        rows = {"row_frame": frame_n, "row_track": track_n, **cells}
        for name, (_, f) in self._files.items():
            shape, dtype = self._shape(name), self._dtype(name)
            a = rows.get(name)
            if a is None:
                a = np.full((n, *shape), self.spec[name][2], dtype)
            a = np.ascontiguousarray(a, dtype=dtype)
            if a.shape != (n, *shape):
                raise ValueError(f"RowWriter: {name} is {a.shape}, expected {(n, *shape)}")
            f.write(a.tobytes())
        self.n_rows += n

    def close(self) -> Path:
        """Assemble the .npz (the header's arrays, then each field's rows) atomically at ``path``."""
        for _, f in self._files.values():
            f.close()
        try:
            with atomic_path(self.path, ".npz") as tmp:
                with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
                    for name, a in _header_arrays(self.cls, self.header).items():
                        with zf.open(f"{name}.npy", "w", force_zip64=True) as m:
                            np.lib.format.write_array(m, np.asanyarray(a), allow_pickle=False)
                    for name, (raw, _) in self._files.items():
                        shape, dtype = (self.n_rows, *self._shape(name)), self._dtype(name)
                        with zf.open(f"{name}.npy", "w", force_zip64=True) as m, open(raw, "rb") as src:
                            np.lib.format.write_array_header_2_0(
                                m, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                                    "shape": shape})
                            while block := src.read(_COPY_BLOCK):
                                m.write(block)
                fsync(tmp)
        finally:
            self._remove()
        return self.path

    def abort(self) -> None:
        for _, f in self._files.values():
            f.close()
        self._remove()

    def _remove(self) -> None:
        for raw, _ in self._files.values():
            raw.unlink(missing_ok=True)

    def __enter__(self) -> "RowWriter":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is not None:
            self.abort()


def fsync(path: Path) -> None:
    with open(path, "rb+") as f:
        os.fsync(f.fileno())


class TrackFile:
    """One keypoint or landmark file, read a window of frames at a time as its tracks type (see
    module doc). ``frame_times``, ``track_ids``, ``image_size`` and the header's other values are
    read at once; ``valid_tk()`` is the whole take's (T, K) validity (small); ``window(start, stop)``
    the frames start:stop with every track column (or only ``cols``). Windows are cheapest asked in
    increasing order (each array is a stream; going back reads it again from its start)."""

    SMALL = ("camera", "image_size", "frame_times", "track_ids", "producer")

    def __init__(self, path: str | os.PathLike, cls, what: str = "track file"):
        self.path, self.cls, self.what = Path(path), cls, what
        names = _member_names(self.path, what)
        small = tuple(n for n in (*self.SMALL, *header_names(cls)) if n in names)
        self.is_rows = all(k in names for k in ROW_KEYS)
        head = read_npz(self.path, what, keys=small + (ROW_KEYS if self.is_rows else ("valid",)))
        missing = [k for k in ("image_size", "frame_times", "track_ids") if k not in head]
        if missing:
            raise UserError(f"{self.path.name} is missing {', '.join(missing)} (not a mamma-kit file or too old)",
                            "run the stage that writes it again")
        self.header = _header_values(cls, head, self.path)
        self.frame_times = self.header["frame_times"]
        self.track_ids = self.header["track_ids"]
        T, K = len(self.frame_times), len(self.track_ids)
        if self.is_rows:
            self.row_frame = np.asarray(head["row_frame"], np.int64)
            self.row_track = np.asarray(head["row_track"], np.int64)
            self.row_start = np.searchsorted(self.row_frame, np.arange(T + 1))
            self._keys = tuple(k for k in names if k not in ROW_KEYS and k not in small)
            xy_key = "xy" if "xy" in self._keys else self._keys[0]
            self.n = self._n_from(self._keys, xy_key)
        else:
            if "valid" not in head:
                raise UserError(f"{self.path.name} is missing valid (not a mamma-kit file or too old)",
                                "run the stage that writes it again")
            self._valid = np.asarray(head["valid"], bool)
            self._keys = tuple(k for k in names if k not in small)
            self.n = self._n_from(self._keys, "xy")
        self.spec = cls.cell_spec(self.n)
        self._keys = tuple(k for k in self._keys if k in self.spec)
        required = [k for k in ("valid", "xy") if k in self.spec and k not in self._keys]
        if required:
            raise UserError(f"{self.path.name} is missing {', '.join(required)} (not a mamma-kit file or too old)",
                            "run the stage that writes it again")
        self._reader: NpzRows | None = None
        self._reader_keys: tuple[str, ...] = ()

    def _n_from(self, keys, xy_key: str) -> int:
        with zipfile.ZipFile(self.path) as z, z.open(f"{xy_key}.npy") as f:
            version = np.lib.format.read_magic(f)
            shape = (np.lib.format.read_array_header_1_0 if version == (1, 0) else
                     np.lib.format.read_array_header_2_0)(f)[0]
        return int(shape[1 if self.is_rows else 2]) if len(shape) > (1 if self.is_rows else 2) else 0

    @property
    def n_frames(self) -> int:
        return len(self.frame_times)

    def valid_tk(self) -> np.ndarray:
        """(T, K) bool: the valid cells of the whole take (reads the rows' valid flags only)."""
        if not self.is_rows:
            return self._valid.copy()
        out = np.zeros((self.n_frames, len(self.track_ids)), bool)
        v = read_npz(self.path, self.what, keys=("valid",))["valid"].astype(bool)
        out[self.row_frame[v], self.row_track[v]] = True
        return out

    def columns_in(self, start: int, stop: int) -> np.ndarray:
        """Sorted track columns with a row (or, in a frames x tracks file, a valid cell) in frames start:stop."""
        start, stop = max(0, int(start)), min(self.n_frames, int(stop))
        if not self.is_rows:
            return np.flatnonzero(self._valid[start:max(start, stop)].any(0))
        return np.unique(self.row_track[self.row_start[start]:self.row_start[max(start, stop)]])

    def _rows_reader(self, keys: tuple[str, ...]) -> NpzRows:
        if self._reader is None or self._reader_keys != keys:
            if self._reader is not None:
                self._reader.close()
            self._reader, self._reader_keys = NpzRows(self.path, keys, self.what), keys
        return self._reader

    def rows(self, start: int, stop: int, keys: tuple[str, ...] | None = None
             ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """The occupied cells of frames start:stop as rows: frame (n,), column (n,) and each field (n, ...)."""
        keys = tuple(k for k in (keys or self._keys) if k in self._keys)
        start, stop = max(0, int(start)), min(self.n_frames, int(stop))
        if self.is_rows:
            a, b = int(self.row_start[start]), int(self.row_start[max(start, stop)])
            d = self._rows_reader(keys).rows(a, b) if keys else {}
            return self.row_frame[a:b], self.row_track[a:b], d
        d = self._rows_reader(keys).rows(start, stop)
        t_n, k_n = np.nonzero(self._valid[start:stop] | self._occupied_dense(d))
        return t_n + start, k_n, {k: v[t_n, k_n] for k, v in d.items()}

    def _occupied_dense(self, d: dict) -> np.ndarray:
        out = None
        for k, v in d.items():
            F, K = v.shape[:2]
            o = ~_is_fill(v.reshape(F * K, int(np.prod(self.spec[k][0]))), self.spec[k][2]).reshape(F, K)
            out = o if out is None else out | o
        return out if out is not None else np.zeros((0, len(self.track_ids)), bool)

    def window(self, start: int = 0, stop: int | None = None, keys: tuple[str, ...] | None = None,
               cols: np.ndarray | None = None):
        """Frames start:stop as the tracks type (frames x tracks arrays of the window): every column, or
        ``cols`` (indices into track_ids; rows of other columns dropped). ``keys``: only these fields
        read (the others an empty cell's)."""
        stop = self.n_frames if stop is None else stop
        start, stop = max(0, int(start)), min(self.n_frames, int(stop))
        stop = max(start, stop)
        t_n, k_n, d = self.rows(start, stop, keys)
        col_index = np.arange(len(self.track_ids))
        track_ids = self.track_ids
        if cols is not None:
            cols = np.asarray(cols, np.int64)
            col_index = np.full(len(self.track_ids), -1, np.int64)
            col_index[cols] = np.arange(len(cols))
            track_ids = self.track_ids[cols]
        kk = col_index[k_n]
        keep = kk >= 0
        cells = empty_cells(self.spec, stop - start, len(track_ids))
        for k, v in d.items():
            cells[k][t_n[keep] - start, kk[keep]] = v[keep]
        if not self.is_rows and "valid" in cells:  # a dense file's valid came with its header
            cells["valid"][:] = self._valid[start:stop][:, cols if cols is not None else slice(None)]
        return self.cls(**{**self.header, "frame_times": self.frame_times[start:stop], "track_ids": track_ids},
                        **cells)

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    def __enter__(self) -> "TrackFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _member_names(path: Path, what: str) -> set[str]:
    if not path.is_file():
        raise UserError(f"{what} not found: {path}", "run the stage that writes it first")
    try:
        with zipfile.ZipFile(path) as z:
            return {n[:-4] for n in z.namelist() if n.endswith(".npy")}
    except (OSError, zipfile.BadZipFile) as e:
        raise UserError(f"{what} {path} is not a readable .npz ({e})", "regenerate it") from None


def load_tracks(cls, path: str | os.PathLike, what: str):
    """A whole keypoint or landmark file (either layout) as its tracks type."""
    with TrackFile(path, cls, what) as f:
        return f.window()


def copy_rows(src: TrackFile, writer: RowWriter, block_frames: int = 256) -> None:
    """Every row of ``src`` appended to ``writer``, a block of frames at a time."""
    for a in range(0, src.n_frames, block_frames):
        t_n, k_n, d = src.rows(a, a + block_frames)
        writer.append(t_n, k_n, **d)
