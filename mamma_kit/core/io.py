"""Atomic writes, hashing and small file helpers (TOML, JSON, npz) shared by all stages.

Every write goes to a temporary file in the destination folder and is renamed into place,
so a killed process never leaves a half-written output that a later run could mistake
for a finished one.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
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
    """Atomically write arrays to .npz (compressed by default)."""
    buf = io.BytesIO()
    (np.savez_compressed if compress else np.savez)(buf, **arrays)
    return atomic_write_bytes(path, buf.getvalue())


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
