"""`mamma-kit board`: print a ChArUco board at true physical scale."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app
from mamma_kit.core import log


@app.command("board", rich_help_panel="Stages")
def board_cmd(
    spec: str = typer.Argument(..., help="Board spec TOML (or a built-in name such as charuco-a1)."),
    out: Path = typer.Option(Path("board.pdf"), "--out", "-o", help="Output: .pdf (vector), .svg or .png."),
    paper: Optional[str] = typer.Option(None, "--paper", help="A0, A1, A2, A3, A4, letter or tabloid "
                                                               "(default: the spec's, else the smallest that fits)."),
    dpi: int = typer.Option(300, "--dpi", help="Resolution of a .png."),
    double_sided: bool = typer.Option(False, "--double-sided", help="Also print the back: a second page with the "
                                      "mirror image, to glue back to back so that cameras behind the board see "
                                      "it too (page 2 of a .pdf; <name>-back.png/.svg beside a .png/.svg)."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Write the board at true scale with its spec and a 100 mm check bar in the margin."""
    from mamma_kit.calibration.board import load_board_spec, print_board

    setup(quiet, json_out)
    s = load_board_spec(spec)
    info = print_board(s, out, paper, dpi, double_sided=double_sided)
    if json_out:
        emit_json(info)
    else:
        log.info(f"{out}: {s.describe()} on {info['paper']}{' landscape' if info['landscape'] else ''}; print at "
                 f"100 % and check that the bar measures 100 mm")
        if double_sided:
            where = "page 2" if len(info["files"]) == 1 else info["files"][1]
            log.info(f"the back ({where}) is the mirror image: turn it over left to right, align it on the front "
                     f"against a window (corner crosses on each other) and glue the two sheets to each other")
