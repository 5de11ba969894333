"""`mamma-kit synth`: render a recipe into a synthetic capture workspace with ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app
from mamma_kit.core import log


@app.command(rich_help_panel="Synthetic captures and training")
def synth(
    recipe: str = typer.Argument(..., help="A recipe .toml, or the name of one in recipes/ (tiny, "
                                           "iphone-outdoor-duo, studio-16cam-solo, crowd-6, board-only)."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder to write the capture workspace (or crop shards) to."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Override the recipe's seed."),
    frames: Optional[int] = typer.Option(None, "--frames", help="Render this many frames (duration = frames / fps)."),
    scale: Optional[float] = typer.Option(None, "--scale", help="Render at this fraction of the recipe's resolution."),
    no_board: bool = typer.Option(False, "--no-board", help="Skip the calibration board session."),
    flash: Optional[List[float]] = typer.Option(None, "--flash", help="Switch a light on at this scene time (s; "
                                                                       "repeatable) for flash sync; exposure and "
                                                                       "rolling shutter from the recipe's \\[flash]."),
    crops: Optional[int] = typer.Option(None, "--crops", help="Instead of a capture, write N person crops for "
                                                               "training MammaNet (shards in --out)."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Render a synthetic capture (videos with audio and timecode, board videos, capture.toml)
    with ground truth in gt/, or a crop dataset with --crops."""
    setup(quiet, json_out)
    if crops is not None:
        from mamma_kit.synth.crops import write_crop_shards

        summary = write_crop_shards(recipe, out, crops, seed=seed)
    else:
        from mamma_kit.synth.capture import synthesize

        summary = synthesize(recipe, out, seed=seed, frames=frames, scale=scale, board=not no_board,
                               flash=flash).summary()
    if json_out:
        emit_json(summary)
    else:
        secs = summary.get("seconds", {})
        if isinstance(secs, dict):
            log.info(f"wrote {out}: " + ", ".join(f"{k} {v}" for k, v in secs.items()))
        else:
            log.info(f"wrote {summary.get('count', '')} crops in {len(summary.get('shards', []))} shards to {out} "
                     f"({secs} s)")
