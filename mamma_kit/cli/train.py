"""`mamma-kit train`: train a MammaNet on crop shards (resumable; writes weights + model card)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app
from mamma_kit.core import log


@app.command("train", rich_help_panel="Synthetic captures and training")
def train_cmd(
    config: Path = typer.Argument(..., help="Training config TOML (e.g. mamma_kit/landmarks/configs/embedded.toml)."),
    resume: bool = typer.Option(False, "--resume", help="Continue from the output folder's checkpoint."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    out: Optional[str] = typer.Option(None, "--out", help="Output folder (overrides \\[train] out)."),
    steps: Optional[int] = typer.Option(None, "--steps", min=1, help="Total steps (overrides \\[train] steps)."),
    for_steps: Optional[int] = typer.Option(None, "--for-steps", min=1, help="Stop this run after N steps with a "
                                                                             "checkpoint (continue with --resume)."),
    for_minutes: Optional[float] = typer.Option(None, "--for-minutes", help="Stop this run after M minutes with a "
                                                                           "checkpoint (continue with --resume)."),
    export: bool = typer.Option(False, "--export", help="Write weights + model card from the checkpoint as it "
                                                        "stands (intermediate), without training."),
    layout_visibility: bool = typer.Option(False, "--layout-visibility", help="With --export: fit the visibility "
                                           "head on the layout of the predicted landmarks (landmarks/layout_vis.py) "
                                           "and ship it in place of the decoder's visibility."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Train MammaNet on `mamma-kit synth --crops` shards; checkpoints every few hundred steps, evaluates on
    held-out shards, and writes <arch>.pt with model_card.md/json in the output folder."""
    from mamma_kit.core.errors import UserError
    from mamma_kit.landmarks.train import export as export_weights
    from mamma_kit.landmarks.train import train

    setup(quiet, json_out)
    if layout_visibility and not export:
        raise UserError("--layout-visibility is a step of --export", "pass --export --layout-visibility after training")
    if export:
        summary = export_weights(config, out=out, device=device, layout_visibility=layout_visibility)
        if json_out:
            emit_json(summary)
        else:
            log.info(f"exported step {summary['steps']}: {summary['weights']}")
        return
    summary = train(config, resume=resume, device=device, out=out, steps=steps, for_steps=for_steps,
                    for_minutes=for_minutes)
    if json_out:
        emit_json(summary)
    elif summary.get("paused"):
        log.info(f"paused at step {summary['steps']} of {summary['of']}; run again with --resume")
    else:
        log.info(f"done: {summary['steps']} steps, weights {summary['weights']}")
