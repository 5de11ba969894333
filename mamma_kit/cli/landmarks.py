"""`mamma-kit landmarks`: MammaNet landmarks for every tracked person (or noisy ground truth)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app
from mamma_kit.core import log
from mamma_kit.core.errors import UserError


@app.command("landmarks", rich_help_panel="Stages")
def landmarks_cmd(
    workspace: Optional[Path] = typer.Argument(None, help="Capture workspace (masks/<cam>.npz + videos)."),
    weights: Optional[Path] = typer.Option(None, "--weights", help="Weights file: a mamma-kit .pt, or the official "
                                                                   "Lightning .ckpt with --arch official."),
    arch: Optional[str] = typer.Option(None, "--arch", help="Architecture: embedded (default), embedded-256, "
                                                            "embedded-single, official, ..."),
    batch: int = typer.Option(8, "--batch", min=1, help="Crops per network batch."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    cameras: Optional[str] = typer.Option(None, "--cameras", help="Comma-separated subset of cameras."),
    source: str = typer.Option("net", "--source", help="net (MammaNet) or gt (noisy ground truth of a synthetic "
                                                       "workspace)."),
    noise: str = typer.Option("0", "--noise", help="--source gt: noise in px, or '1.2%' of the box height."),
    outliers: float = typer.Option(0.0, "--outliers", help="--source gt: fraction of landmarks made outliers."),
    seed: int = typer.Option(0, "--seed", help="--source gt: random seed."),
    hands: str = typer.Option("auto", "--hands", help="Hand refinement (a second network reads each hand at the "
                                                       "frame's resolution): auto (the shipped one where it fits "
                                                       "the model), off, or a hand weights .pt."),
    smooth_s: Optional[float] = typer.Option(None, "--smooth-s", min=0.0, help="The network's contact and "
                                             "visibility smoothed over this many seconds of each track (contact "
                                             "also over its nearest landmarks); default 0.1, 0 = off."),
    contact: str = typer.Option("auto", "--contact", help="Whose person-contact head: auto (the shipped "
                                                           "single-query network's, which reads contact better, "
                                                           "under a keypoint-guided model), off (the model's own), "
                                                           "or an image-only weights .pt."),
    describe: bool = typer.Option(False, "--describe", help="Print the architecture's state-dict names and shapes."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    unit_frames: Optional[int] = typer.Option(None, "--unit-frames", min=0, help="Frames per unit of work "
                                              "(0: a camera per unit; default MAMMA_KIT_UNIT_FRAMES or 0); "
                                              "the results do not depend on it."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Dense landmarks (xy, sigma, visibility, contact, floor contact) for every tracked person and frame.
    The network's units (a camera, or --unit-frames of it) run side by side, one thread each (the
    root --workers sets how many): the numbers do not depend on the machine's cores or load."""
    setup(quiet, json_out)
    if describe:
        from mamma_kit.landmarks.config import DEFAULT_ARCH
        from mamma_kit.landmarks.model import state_dict_shapes

        shapes = state_dict_shapes(arch or DEFAULT_ARCH)
        if json_out:
            emit_json([{"name": k, "shape": list(s)} for k, s in shapes])
        else:
            for k, s in shapes:
                typer.echo(f"{k} ({', '.join(map(str, s))}{',' if len(s) == 1 else ''})")
        return
    if source not in ("net", "gt"):
        raise UserError(f"--source '{source}' is unknown", "use --source net or --source gt")
    if device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise UserError("--device cuda but torch sees no CUDA device", "use --device cpu")
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.landmarks.stage import run_landmarks

    loaded = None
    if source == "net":  # load (and validate) the weights first: a bad --weights is the first thing to report
        from mamma_kit.landmarks.weights import load_model

        loaded = load_model(weights, arch, device)
    if workspace is None:
        raise UserError("no WORKSPACE given", "run `mamma-kit landmarks WORKSPACE` (or --describe to list the weights)")
    res = run_landmarks(Workspace(workspace), source=source, batch=batch, device=device, cameras=cameras, noise=noise,
                        outliers=outliers, seed=seed, force=force, loaded=loaded,
                        unit_frames=unit_frames, hands=hands, smooth_s=smooth_s, contact=contact)
    if json_out:
        emit_json(res)
