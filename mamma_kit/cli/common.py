"""Helpers shared by the command modules: JSON output, quiet mode, option types."""

from __future__ import annotations

import sys
from typing import Any

import typer

from mamma_kit.core import log
from mamma_kit.core.io import to_json

JsonOpt = typer.Option(False, "--json", help="Print a JSON summary on stdout.")
QuietOpt = typer.Option(False, "--quiet", "-q", help="No progress or log output on stderr.")


def setup(quiet: bool = False, json_out: bool = False) -> None:
    """Apply --quiet (and keep stdout clean for --json)."""
    log.set_quiet(quiet)


def emit_json(data: Any) -> None:
    sys.stdout.write(to_json(data) + "\n")
    sys.stdout.flush()
