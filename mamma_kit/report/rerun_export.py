"""Optional: the rig and the fitted meshes over time as a rerun recording (report/recording.rrd).

Needs the ``rerun`` package (``pip install rerun-sdk``), which mamma-kit does not depend on.
Open the file with ``rerun report/recording.rrd``. Cameras are logged once (pose and pinhole
intrinsics, OpenCV axes); each person's mesh on the reference-clock timeline "time", at most
MAX_FRAMES frames (evenly strided) so long captures stay a manageable file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.colour import person_colour
from mamma_kit.report.data import ReportData

MAX_FRAMES = 900
POSE_CHUNK = 64


def require_rerun():
    try:
        import rerun
    except ImportError:
        raise UserError("--rerun needs the rerun package, which is not installed",
                        "pip install rerun-sdk (or leave out --rerun)") from None
    return rerun


def _set_time(rr, seconds: float) -> None:
    if hasattr(rr, "set_time"):  # rerun >= 0.23
        rr.set_time("time", duration=seconds)
    else:
        rr.set_time_seconds("time", seconds)


def write_recording(data: ReportData, path: Path) -> Path:
    """Write the recording; returns its path."""
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.core.io import atomic_path

    rr = require_rerun()
    rec = rr.RecordingStream("mamma-kit report")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        rec.save(str(tmp))
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if data.rig is not None:
            for c in data.rig:
                rec.log(f"world/cameras/{c.name}", rr.Transform3D(translation=c.center, mat3x3=c.R.T), static=True)
                rec.log(f"world/cameras/{c.name}/image", rr.Pinhole(image_from_camera=c.K, resolution=list(c.size)),
                        static=True)
        faces = data.body_model.np.faces.astype(np.uint32)
        for person in data.people:
            T = person.result.num_frames
            frames = np.arange(0, T, max(1, -(-T // MAX_FRAMES)))
            colour = (np.asarray(person_colour(person.id)) * 255).astype(np.uint8)
            entity = f"world/people/person_{person.id}"
            partial = hasattr(rr.Mesh3D, "from_fields")  # rerun >= 0.22: triangles once, vertices per frame
            if partial:
                rec.log(entity, rr.Mesh3D.from_fields(triangle_indices=faces, albedo_factor=colour), static=True)
            for s in range(0, len(frames), POSE_CHUNK):
                sel = frames[s:s + POSE_CHUNK]
                V_nv3, _ = pose_mesh_np(data.body_model, person.result.params(sel))
                for i, V_v3 in zip(sel, V_nv3):
                    _set_time(rec, float(person.frame_times[i]))
                    rec.log(entity, rr.Mesh3D.from_fields(vertex_positions=V_v3) if partial else
                            rr.Mesh3D(vertex_positions=V_v3, triangle_indices=faces, albedo_factor=colour))
        rec.flush()
        rec.disconnect()
    return path
