"""`mamma-kit calib ...`: work with calibration files (convert between tools' formats)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app
from mamma_kit.core import log

calib_app = typer.Typer(help="Calibration files: convert between mamma-kit, MAMMA YAML, EasyMocap, anipose, "
                             "Caliscope, OpenCV JSON and Vicon .xcp; read Qualisys .qca.txt.", no_args_is_help=True)
app.add_typer(calib_app, name="calib", rich_help_panel="Tools")

FMT_HELP = ("mamma-kit | mamma-yaml | easymocap | anipose | caliscope | opencv-json | vicon-xcp | qualisys (read "
            "only; .qca.txt) (inferred from the name if omitted)")


@calib_app.command("convert")
def convert_cmd(
    src: Path = typer.Argument(..., help="Input calibration (for easymocap: intri.yml, extri.yml or their folder)."),
    dst: Path = typer.Argument(..., help="Output calibration path (for easymocap: a folder or intri.yml)."),
    from_fmt: Optional[str] = typer.Option(None, "--from", help=FMT_HELP),
    to_fmt: Optional[str] = typer.Option(None, "--to", help=FMT_HELP),
    names: Optional[str] = typer.Option(None, "--names", help="Comma-separated new camera names, in file order "
                                                              "(e.g. to match video file stems)."),
    scale: float = typer.Option(1.0, "--scale", help="Multiply translations (0.001 for a file in millimetres)."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Convert a calibration file between formats; projections are preserved exactly where both formats hold the
    lens model (a Vicon lens written to an OpenCV format says how far its projections move)."""
    from mamma_kit.calibration.formats import convert

    setup(quiet, json_out)
    rig, f_in, f_out = convert(src, dst, from_fmt, to_fmt, names.split(",") if names else None, scale)
    if json_out:
        emit_json({"input": str(src), "output": str(dst), "from": f_in, "to": f_out, "cameras": rig.names})
    else:
        log.info(f"{src} ({f_in}) -> {dst} ({f_out}): {len(rig)} cameras: {', '.join(rig.names)}")
