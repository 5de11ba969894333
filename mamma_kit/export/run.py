"""``mamma-kit export``: a workspace's fitted people in other tools' formats.

gltf (one .glb: every person, the cameras and the floor), bvh, trc, c3d and amass (one file per
person: export/person_<k>.<suffix>). ``out``: a file for the formats that make one (gltf, or any
format with one person), else a folder.
"""

from __future__ import annotations

from pathlib import Path

from mamma_kit.core.errors import UserError

FORMATS = {"gltf": ".glb", "bvh": ".bvh", "trc": ".trc", "c3d": ".c3d", "amass": ".npz"}


def _people(ws, persons: list[int] | None) -> list[tuple[int, object]]:
    from mamma_kit.core.smplxfile import read_smplx_result

    files = {int(p.stem.split("_")[1]): p for p in ws.person_files()}
    if not files:
        raise UserError(f"{ws.root} has no fitted people (smplx/person_<k>.npz)", f"run `mamma-kit fit {ws.root}` first")
    unknown = sorted(set(persons or ()) - set(files))
    if unknown:
        raise UserError(f"no fitted person {', '.join(map(str, unknown))} in {ws.root}",
                        f"pick from the fitted persons: {', '.join(map(str, sorted(files)))}")
    return [(k, read_smplx_result(files[k])) for k in sorted(persons or files)]


def _model(ws, people):
    """The body model the people were fitted with: capture.toml's, refused if its file differs."""
    from mamma_kit.body.model import load_body_model

    spec = ws.load_capture().body_model if ws.capture_toml.is_file() else "open"
    r = people[0][1]
    model = load_body_model(spec, r.gender)
    fitted = {res.body_model_sha256 for _, res in people}
    if fitted != {model.sha256}:
        raise UserError(f"the people were fitted with body model {r.body_model_name} ({r.body_model_sha256[:12]}), "
                        f"but capture.toml's '{spec}' is {model.name} ({model.sha256[:12]})",
                        "set [capture] body_model in capture.toml to the file the fit used")
    return model


def _targets(ws, fmt: str, pids: list[int], out: Path | None) -> dict:
    """Output path per person id (gltf: one path under key None)."""
    suffix = FORMATS[fmt]
    one_file = fmt == "gltf" or len(pids) == 1
    if out is not None and out.suffix:
        if not one_file:
            raise UserError(f"--out {out} is one file, but {fmt} writes one file per person ({len(pids)} persons)",
                            "give --out a folder, or one --person")
        if fmt == "gltf" and out.suffix.lower() not in (".glb", ".gltf"):
            raise UserError(f"--out {out}: glTF files end in .glb or .gltf", "use --out NAME.glb")
        return {None: out} if fmt == "gltf" else {pids[0]: out}
    folder = out if out is not None else ws.export_dir
    if fmt == "gltf":
        return {None: folder / "capture.glb"}
    return {k: folder / f"person_{k}{suffix}" for k in pids}


def export_workspace(ws, fmt: str, persons: list[int] | None = None, out: Path | None = None) -> dict:
    """Write the fitted people of ``ws`` as ``fmt``; returns a JSON-able summary."""
    if fmt not in FORMATS:
        raise UserError(f"unknown export format '{fmt}'", f"use one of: {', '.join(FORMATS)}")
    people = _people(ws, persons)
    targets = _targets(ws, fmt, [k for k, _ in people], Path(out) if out is not None else None)
    for p in targets.values():
        p.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "amass":  # parameters only: no body model needed
        from mamma_kit.export.amass import write_amass

        files = [write_amass(targets[k], r) for k, r in people]
        return {"format": fmt, "files": files}
    model = _model(ws, people)
    if fmt == "gltf":
        from mamma_kit.core.calibfile import read_calibration
        from mamma_kit.core.colour import person_colour
        from mamma_kit.export.gltf import write_gltf
        from mamma_kit import __version__

        rig = read_calibration(ws.calibration)[0] if ws.calibration.is_file() else None
        summary = write_gltf(targets[None], people, model, rig, colours={k: person_colour(k) for k, _ in people},
                             generator=f"mamma-kit {__version__}")
        return {"format": fmt, "files": [summary]}
    if fmt == "bvh":
        from mamma_kit.export.bvh import write_bvh
        from mamma_kit.export.motion import skeleton_motion

        return {"format": fmt, "files": [write_bvh(targets[k], skeleton_motion(model, r)) for k, r in people]}
    from mamma_kit.export.c3d import write_c3d
    from mamma_kit.export.markers import marker_positions
    from mamma_kit.export.motion import uniform_frames
    from mamma_kit.export.trc import write_trc

    write = write_trc if fmt == "trc" else write_c3d
    files = []
    for k, r in people:
        names, xyz = marker_positions(model, r)
        grid_t, n = uniform_frames(r.frame_times, r.fps)
        files.append(write(targets[k], names, xyz, grid_t, n, r.fps))
    return {"format": fmt, "files": files}
