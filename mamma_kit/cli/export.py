"""`mamma-kit export`: the fitted people as glTF, BVH, C3D, TRC or AMASS-style npz -> export/."""

from __future__ import annotations

from pathlib import Path

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app

FORMAT_HELP = ("gltf: one .glb with every person's animated mesh, the cameras and the floor (Blender, three.js, "
               "Unity, Unreal); bvh: each person's skeleton (Blender, MotionBuilder, game engines); trc / c3d: "
               "virtual markers on the body surface (OpenSim, Pose2Sim / Vicon, Visual3D, Mokka); amass: SMPL-X "
               "parameters as AMASS stores them (smplx code).")


@app.command("export", rich_help_panel="Stages")
def export_cmd(
    workspace: Path = typer.Argument(..., help="Capture workspace with fitted people (smplx/)."),
    fmt: str = typer.Option("gltf", "--format", "-f", help=FORMAT_HELP),
    person: list[int] = typer.Option(None, "--person", "-p", help="Only this person (repeatable); default: all."),
    out: Path = typer.Option(None, "--out", "-o", help="A file (gltf, or one person) or a folder; default: "
                                                       "WORKSPACE/export/ (capture.glb, person_<k>.<format>)."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Write the fitted people in a format other tools open."""
    from mamma_kit.core import log
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.export.run import export_workspace

    setup(quiet, json_out)
    summary = export_workspace(Workspace(workspace), fmt.lower(), list(person or []) or None, out)
    if json_out:
        emit_json(summary)
    else:
        for f in summary["files"]:
            log.info(f"wrote {f['path']}")
