"""Logging and progress on stderr (results go to files, --json to stdout).

``set_quiet(True)`` silences both; progress bars are drawn only on a terminal.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterable, Iterator, TypeVar

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

T = TypeVar("T")

console = Console(stderr=True, highlight=False)
_quiet = False


def set_quiet(quiet: bool) -> None:
    global _quiet
    _quiet = bool(quiet)


def is_quiet() -> bool:
    return _quiet


def info(msg: str) -> None:
    if not _quiet:
        console.print(msg)


def warn(msg: str) -> None:
    # warnings are shown even with --quiet: they say something the user must know
    console.print(f"[yellow]warning:[/yellow] {msg}")


def progress_bar() -> Progress:
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), TimeRemainingColumn(), console=console,
                    disable=_quiet or not console.is_terminal, transient=True)


@contextmanager
def progress(description: str, total: int | None) -> Iterator:
    """``with progress("keypoints cam1", n) as advance: ... advance(k)`` draws one bar."""
    with progress_bar() as p:
        task = p.add_task(description, total=total)
        yield lambda n=1: p.advance(task, n)


def track(items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """Iterate with a progress bar (silent with --quiet or when stderr is not a terminal)."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with progress_bar() as p:
        task = p.add_task(description, total=total)
        for x in items:
            yield x
            p.advance(task)
