"""`mamma-kit eval`: compare a synthetic workspace's results with its ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app
from mamma_kit.core import log
from mamma_kit.core.io import to_json


@app.command("eval", rich_help_panel="Synthetic captures and training")
def eval_cmd(
    workspace: Path = typer.Argument(..., help="A synthetic capture workspace (with gt/)."),
    only: Optional[str] = typer.Option(None, "--only", help="Comma-separated groups: calibration, timing, masks, "
                                                            "landmarks, identities, fit."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Every stage's metrics against ground truth, in one JSON object grouped by stage."""
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.stage import evaluate_workspace

    setup(quiet, json_out)
    result = evaluate_workspace(Workspace(workspace), only.split(",") if only else None)
    if json_out:
        emit_json(result)
    else:
        log.console.print_json(to_json(result))
