"""Stage manifests: a stage is skipped only when its inputs, settings and outputs are
exactly what they were when it last finished.

``.cache/<stage>.json`` records the sha256 of every input file, the settings (and their
hash), the mamma-kit version, the versions of the numerical libraries and the CPU's vector
instructions (core/reproducible.runtime_record: what could change the numbers), and the
sha256 of every output; for information also how it ran (threads, executor, seconds). A stage
is *fresh* when inputs, settings, versions and outputs all match; anything else (a changed
video, a new setting, another torch, a deleted or edited output, an interrupted run that never
wrote its manifest) makes it stale, with the reason.

Hashing big videos on every run would be slow, so file hashes are memoised in
``.cache/file-hashes.json`` by (size, mtime_ns): a file touched in any way is rehashed.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from mamma_kit import __version__
from mamma_kit.core.io import read_json, sha256_file, sha256_json, write_json
from mamma_kit.core.reproducible import runtime_record, threads_record


class FileHasher:
    """sha256 of files, memoised by (path, size, mtime_ns) in a JSON file."""

    def __init__(self, memo_path: Path | None):
        self.memo_path = memo_path
        self._memo: dict[str, list] = {}
        if memo_path is not None and memo_path.is_file():
            try:
                self._memo = json.loads(memo_path.read_text())
            except (OSError, json.JSONDecodeError):
                self._memo = {}
        self._dirty = False

    def __call__(self, path: Path) -> str | None:
        path = Path(path)
        try:
            st = path.stat()
        except FileNotFoundError:
            return None
        if path.is_dir():
            return sha256_json(sorted((str(p.relative_to(path)), self(p))
                                      for p in path.rglob("*") if p.is_file() and not p.name.startswith(".")))
        key = str(path.resolve())
        hit = self._memo.get(key)
        if hit and hit[0] == st.st_size and hit[1] == st.st_mtime_ns:
            return hit[2]
        digest = sha256_file(path)
        self._memo[key] = [st.st_size, st.st_mtime_ns, digest]
        self._dirty = True
        return digest

    def save(self) -> None:
        if self.memo_path is not None and self._dirty:
            write_json(self.memo_path, self._memo)
            self._dirty = False


@dataclass
class Freshness:
    fresh: bool
    reason: str


class StageManifest:
    """Manifest of one stage in a workspace.

    >>> m = StageManifest(ws.cache_dir, "sync", root=ws.root)
    >>> state = m.check(inputs, settings)
    >>> if not state.fresh: run(); m.record(inputs, settings, outputs, summary)
    """

    def __init__(self, cache_dir: Path, stage: str, root: Path):
        self.cache_dir = Path(cache_dir)
        self.stage = stage
        self.root = Path(root)
        self.path = self.cache_dir / f"{stage}.json"
        self.hasher = FileHasher(self.cache_dir / "file-hashes.json")

    def _rel(self, p: Path) -> str:
        p = Path(p).resolve()
        try:
            return str(p.relative_to(self.root.resolve()))
        except ValueError:
            return str(p)

    def _hashes(self, paths: Iterable[Path]) -> dict[str, str | None]:
        return {self._rel(p): self.hasher(Path(p)) for p in paths}

    def load(self) -> dict | None:
        if not self.path.is_file():
            return None
        try:
            return read_json(self.path)
        except Exception:
            return None

    def check(self, inputs: Iterable[Path], settings: Any) -> Freshness:
        old = self.load()
        if old is None:
            return Freshness(False, "never ran")
        if old.get("version") != __version__:
            return Freshness(False, f"made by mamma-kit {old.get('version')}, now {__version__}")
        if old.get("settings_sha256") != sha256_json(settings):
            return Freshness(False, "settings changed")
        why = runtime_change(old.get("runtime"), runtime_record())
        if why:
            return Freshness(False, why)
        now = self._hashes(inputs)
        before = old.get("inputs", {})
        changed = sorted(k for k in set(now) | set(before) if now.get(k) != before.get(k))
        if changed:
            return Freshness(False, f"input changed: {', '.join(changed[:3])}{' ...' if len(changed) > 3 else ''}")
        outs = old.get("outputs", {})
        for rel, digest in outs.items():
            p = Path(rel) if Path(rel).is_absolute() else self.root / rel
            if self.hasher(p) != digest:
                return Freshness(False, f"output missing or edited: {rel}")
        self.hasher.save()
        return Freshness(True, "inputs unchanged")

    def reuse(self, state: Freshness, force: bool, output: Path) -> dict | None:
        """The summary of the run that made ``output``, marked skipped (its own "skipped" is False),
        when ``state`` (this manifest's check) is fresh, not ``force``d and ``output`` is there; else None."""
        from mamma_kit.core import log

        if not (state.fresh and not force and Path(output).is_file()):
            return None
        log.info(f"{self.stage}: up to date ({state.reason}); skipped (--force recomputes)")
        return {**(self.load() or {}).get("summary", {}), "stage": self.stage, "skipped": True, "reason": state.reason}

    def record(self, inputs: Iterable[Path], settings: Any, outputs: Iterable[Path],
               summary: dict | None = None, seconds: float | None = None) -> Path:
        """Write the manifest after the stage's outputs are complete (atomically)."""
        from mamma_kit.core.executor import executor_name

        data = {
            "stage": self.stage,
            "version": __version__,
            "settings_sha256": sha256_json(settings),
            "settings": settings,
            "runtime": runtime_record(),
            "ran_with": {**threads_record(), "executor": executor_name()},  # cannot change the numbers
            "inputs": self._hashes(inputs),
            "outputs": self._hashes(outputs),
            "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "seconds": seconds,
            "summary": summary or {},
        }
        write_json(self.path, data)
        self.hasher.save()
        return self.path

    def update_outputs(self, outputs: Iterable[Path]) -> None:
        """Record ``outputs`` as they are now in an existing manifest (a later step that refines a
        stage's output in place, e.g. `calibrate --people`); nothing without a manifest."""
        data = self.load()
        if data is None:
            return
        data["outputs"] = {**data.get("outputs", {}), **self._hashes(outputs)}
        write_json(self.path, data)
        self.hasher.save()

    def invalidate(self) -> None:
        if self.path.exists():
            os.remove(self.path)


def runtime_change(before: dict | None, now: dict) -> str | None:
    """Why a result made under ``before`` (a manifest's runtime) may differ from one made now, or None."""
    if not before:
        return "made before manifests recorded library versions"
    for key in ("machine", "cpu_vector"):
        if before.get(key) != now.get(key):
            return f"made on {key} {before.get(key)}, now {now.get(key)}"
    old_p, new_p = before.get("packages", {}), now.get("packages", {})
    changed = sorted(p for p in set(old_p) | set(new_p) if old_p.get(p) != new_p.get(p))
    if changed:
        p = changed[0]
        return f"made with {p} {old_p.get(p, '(none)')}, now {new_p.get(p, '(none)')}" + \
            (f" (+{len(changed) - 1} more)" if len(changed) > 1 else "")
    return None


def producer(command: str, inputs: dict[str, str] | None = None) -> dict:
    """The 'producer' record every output carries: tool version, command, input hashes."""
    return {"tool": "mamma-kit", "version": __version__, "command": command, "inputs": inputs or {}}
