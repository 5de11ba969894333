"""`mamma-kit body`: inspect the body model and export a fitted frame as a mesh."""

from __future__ import annotations

from pathlib import Path

import typer

from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.cli.root import app

body_app = typer.Typer(help="Body model: info, mesh export.", no_args_is_help=True)
app.add_typer(body_app, name="body", rich_help_panel="Tools")

BodyModelOpt = typer.Option("open", "--body-model",
                            help="'open' (embedded open body) or an SMPL-X .npz file / folder with SMPLX_*.npz.")
GenderOpt = typer.Option("neutral", "--gender", help="neutral, male or female (for a folder of SMPL-X files).")


@body_app.command("info")
def info(body_model: str = BodyModelOpt, gender: str = GenderOpt, json_out: bool = JsonOpt,
         quiet: bool = QuietOpt) -> None:
    """Name, sha256, vertices, faces, joints, landmarks and shape components of a body model."""
    from mamma_kit.body.model import load_body_model

    setup(quiet, json_out)
    m = load_body_model(body_model, gender)
    s = m.summary()
    if json_out:
        emit_json(s)
        return
    for k, v in s.items():
        typer.echo(f"{k:>24}: {v}")


@body_app.command("export")
def export(params: Path = typer.Argument(..., help="A per-person SMPL-X result (smplx/person_<k>.npz)."),
           frame: int = typer.Option(0, "--frame", help="Frame index (0-based; negative counts from the end)."),
           out: Path = typer.Option(..., "--out", help="Output mesh: .obj or .ply."),
           body_model: str = BodyModelOpt, gender: str = GenderOpt, json_out: bool = JsonOpt,
           quiet: bool = QuietOpt) -> None:
    """Pose the body of one frame of a result file and write it as a mesh (world frame, metres)."""
    import trimesh

    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core import log
    from mamma_kit.core.errors import UserError
    from mamma_kit.core.io import atomic_path
    from mamma_kit.core.smplxfile import read_smplx_result

    setup(quiet, json_out)
    if out.suffix.lower() not in (".obj", ".ply"):
        raise UserError(f"cannot write {out.suffix or 'a file without suffix'}: {out}", "use --out mesh.obj or mesh.ply")
    r = read_smplx_result(params)
    if not -r.num_frames <= frame < r.num_frames:
        raise UserError(f"frame {frame} is outside 0..{r.num_frames - 1} of {params}", "pick an existing frame")
    m = load_body_model(body_model, gender)
    if r.body_model_sha256 != m.sha256:
        log.warn(f"{params} was made with body model {r.body_model_name} ({r.body_model_sha256[:12]}), "
                 f"exporting with {m.name} ({m.sha256[:12]}): pass the same --body-model for a faithful mesh")
    v, _ = pose_mesh_np(m, r.params(frame % r.num_frames))
    mesh = trimesh.Trimesh(v[0], m.np.faces, process=False)
    with atomic_path(out) as tmp:
        mesh.export(tmp, file_type=out.suffix.lower()[1:])
    summary = {"out": str(out), "frame": frame % r.num_frames, "time": float(r.frame_times[frame]),
               "vertices": m.num_vertices, "faces": m.num_faces, "body_model": m.name, "sha256": m.sha256}
    if json_out:
        emit_json(summary)
    else:
        log.info(f"wrote {out} (frame {summary['frame']}, {m.num_vertices} vertices)")
