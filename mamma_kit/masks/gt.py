"""`--backend gt`: the ground-truth person masks of a synthetic workspace (gt/masks/<cam>.npz),
so later stages can be tested without the tracker's errors. Track id = person id."""

from __future__ import annotations

from mamma_kit.core.errors import UserError
from mamma_kit.core.tracks import MaskTracks
from mamma_kit.masks.base import CameraInput, track_summary


class GtBackend:
    name = "gt"

    def track_camera(self, cam: CameraInput) -> tuple[MaskTracks, dict]:
        path = cam.workspace_root / "gt" / "masks" / f"{cam.name}.npz"
        if not path.is_file():
            raise UserError(f"no ground-truth masks for {cam.name} (gt/masks/{cam.name}.npz)",
                            "--backend gt works on synthetic workspaces made by `mamma-kit synth`; "
                            "use --backend builtin or sam2 on real captures")
        mt = MaskTracks.load(path)
        mt.camera = cam.name
        return mt, track_summary(mt)
