"""Atomic writes, hashing and small file helpers (TOML, JSON, npz) shared by all stages.

Every write goes to a temporary file in the destination folder and is renamed into place,
so a killed process never leaves a half-written output that a later run could mistake
for a finished one.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
import tomllib
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import tomli_w

from mamma_kit.core.errors import UserError


_UMASK = os.umask(0)
os.umask(_UMASK)


def temp_beside(path: str | os.PathLike, suffix: str | None = None) -> Path:
    """A new empty temporary file in ``path``'s folder, keeping its suffix; rename it onto
    ``path`` with os.replace when complete (same filesystem, so the rename is atomic)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = suffix if suffix is not None else "".join(path.suffixes)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; outputs should look like any other file
    return Path(tmp)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    The temporary name keeps the suffix so libraries that dispatch on it (PyAV, numpy)
    behave as for the final name.
    """
    tmp_path = temp_beside(path, suffix)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def _plain(obj: Any, json_safe: bool = False) -> Any:
    """Convert numpy scalars/arrays and paths into JSON/TOML-friendly Python values
    (``json_safe``: NaN and infinities become null, which JSON has instead)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v, json_safe) for k, v in obj.items() if v is not None}
    if isinstance(obj, (list, tuple)):
        return [_plain(v, json_safe) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist(), json_safe)
    if isinstance(obj, np.generic):
        obj = obj.item()
    if json_safe and isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_toml(path: str | os.PathLike, data: dict) -> Path:
    return atomic_write_text(path, tomli_w.dumps(_plain(data)))


def read_toml(path: str | os.PathLike, what: str = "TOML file") -> dict:
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{what} not found: {p}", "check the path")
    try:
        with open(p, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{what} {p} is not valid TOML ({e})", "fix the syntax at that line") from None


def to_json(data: Any, indent: int | None = 2) -> str:
    return json.dumps(_plain(data, json_safe=True), indent=indent, allow_nan=False, default=str)


def write_json(path: str | os.PathLike, data: Any) -> Path:
    return atomic_write_text(path, to_json(data) + "\n")


def read_json(path: str | os.PathLike, what: str = "JSON file") -> Any:
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{what} not found: {p}", "check the path")
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise UserError(f"{what} {p} is not valid JSON ({e})", "regenerate it") from None


def write_npz(path: str | os.PathLike, compress: bool = True, **arrays: Any) -> Path:
    """Atomically write arrays to .npz (compressed by default), streamed into the temporary file: a
    long take's landmark file is hundreds of MB, and a buffer in memory held it twice."""
    with atomic_path(path, ".npz") as tmp:
        with open(tmp, "wb") as f:
            (np.savez_compressed if compress else np.savez)(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)


def read_npz(path: str | os.PathLike, what: str = "array file", keys: tuple[str, ...] | None = None
             ) -> dict[str, np.ndarray]:
    """Load every array of an .npz (or only ``keys``: the others are not read) without unpickling anything."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{what} not found: {p}", "run the stage that writes it first")
    try:
        with np.load(p, allow_pickle=False) as z:
            return {k: z[k] for k in z.files if keys is None or k in keys}
    except ValueError as e:
        if "pickle" in str(e).lower():
            raise UserError(
                f"{what} {p} holds pickled Python objects, which mamma-kit refuses to load",
                "re-save it with plain arrays (np.savez with numeric/str arrays only)",
            ) from None
        raise UserError(f"{what} {p} is not a readable .npz ({e})", "regenerate it") from None
    except (OSError, EOFError) as e:
        raise UserError(f"{what} {p} is corrupt or truncated ({e})", "regenerate it") from None


class NpzRows:
    """Rows (along the first axis: frames) of some arrays of an .npz, read in order without holding
    the whole arrays: each member is decompressed as a stream, and only the rows last asked for are
    kept, so a long take's per-frame arrays cost memory in proportion to the rows asked for at once.

    ``rows(start, stop)`` -> {key: array (stop - start, ...)}. Ask in increasing order; asking again
    for rows at or after the last block's start is cheap, asking further back reads the members
    again from their start. Members numpy does not store as plain C-order rows (Fortran order,
    object arrays, unknown header versions) are read whole instead."""

    def __init__(self, path: str | os.PathLike, keys: tuple[str, ...], what: str = "array file"):
        import zipfile

        self.path, self.keys, self.what = Path(path), tuple(keys), what
        if not self.path.is_file():
            raise UserError(f"{what} not found: {self.path}", "run the stage that writes it first")
        try:
            self._zip = zipfile.ZipFile(self.path)
        except (OSError, zipfile.BadZipFile) as e:
            raise UserError(f"{what} {self.path} is not a readable .npz ({e})", "regenerate it") from None
        names = set(self._zip.namelist())
        missing = [k for k in self.keys if f"{k}.npy" not in names]
        if missing:
            raise UserError(f"{self.path.name} is missing {', '.join(missing)} (not a mamma-kit file or too old)",
                            "run the stage that writes it again")
        self._stream: dict[str, Any] = {}
        self._whole: dict[str, np.ndarray] = {}
        self.shape: dict[str, tuple[int, ...]] = {}
        self.dtype: dict[str, np.dtype] = {}
        for k in self.keys:
            self._open(k)
        lengths = {s[0] if s else 0 for s in self.shape.values()}
        if len(lengths) != 1:
            raise UserError(f"{what} {self.path} holds arrays of different lengths", "regenerate it")
        self.n_rows = lengths.pop() if lengths else 0
        self._pos = 0  # the row every stream is at
        self._start = 0  # the first row of the block kept
        self._block: dict[str, np.ndarray] = {k: self._empty(k) for k in self.keys}

    def _open(self, k: str) -> None:
        f = self._zip.open(f"{k}.npy")
        version = np.lib.format.read_magic(f)
        readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
        plain = False
        if version in readers:
            shape, fortran, dtype = readers[version](f)
            plain = not fortran and not dtype.hasobject and len(shape) >= 1
        if not plain:  # read whole, as np.load would
            f.close()
            with self._zip.open(f"{k}.npy") as g:
                a = np.lib.format.read_array(g, allow_pickle=False)
            self._whole[k] = a
            shape, dtype = a.shape, a.dtype
        else:
            self._stream[k] = f
        self.shape[k], self.dtype[k] = tuple(shape), np.dtype(dtype)

    def _empty(self, k: str) -> np.ndarray:
        return np.zeros((0, *self.shape[k][1:]), self.dtype[k])

    def _row_bytes(self, k: str) -> int:
        return int(np.prod(self.shape[k][1:], dtype=np.int64)) * self.dtype[k].itemsize

    def _read(self, k: str, n: int) -> np.ndarray:
        nbytes = n * self._row_bytes(k)
        buf = self._stream[k].read(nbytes)
        if len(buf) != nbytes:
            raise UserError(f"{self.what} {self.path} is corrupt or truncated", "regenerate it")
        return np.frombuffer(buf, self.dtype[k]).reshape(n, *self.shape[k][1:])

    def rows(self, start: int, stop: int) -> dict[str, np.ndarray]:
        start, stop = max(0, int(start)), min(self.n_rows, int(stop))
        stop = max(start, stop)
        if start < self._start:  # further back than the block kept: from the top again
            for k in self._stream:
                self._stream[k].close()
                self._open(k)
            self._pos = self._start = 0
            self._block = {k: self._empty(k) for k in self.keys}
        if start > self._pos:  # skip what nobody asked for, in bounded reads
            for k in self._stream:
                left = start - self._pos
                step = max(1, (64 << 20) // max(self._row_bytes(k), 1))
                while left > 0:
                    self._read(k, min(step, left))
                    left -= min(step, left)
            self._pos = self._start = start
            self._block = {k: self._empty(k) for k in self.keys}
        new = max(0, stop - self._pos)
        out, block = {}, {}
        for k in self.keys:
            if k in self._whole:
                out[k] = block[k] = self._whole[k][start:stop]
                continue
            kept = self._block[k][start - self._start:]
            block[k] = np.concatenate([kept, self._read(k, new)]) if new else kept  # rows start:_pos, kept
            out[k] = block[k][:stop - start]
        self._pos = max(self._pos, stop)
        self._start, self._block = start, block
        return out

    def close(self) -> None:
        for f in self._stream.values():
            f.close()
        self._zip.close()

    def __enter__(self) -> "NpzRows":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 22) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while True:
            block = f.read(chunk)
            if not block:
                break
            h.update(block)
    return h.hexdigest()


def sha256_json(obj: Any) -> str:
    """Hash of a JSON-able object (stable key order), e.g. a stage's settings."""
    return sha256_bytes(json.dumps(_plain(obj), sort_keys=True, separators=(",", ":")).encode())
