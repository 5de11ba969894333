"""A contact sheet of the `pose` tracks and BlazePose keypoints on a workspace: one row per camera,
a few frames per row, masks tinted by track and skeletons drawn (docs/keypoints-real.png).

    python benchmarks/keypoints_contact_sheet.py WORKSPACE --out docs/keypoints-real.png

WORKSPACE needs masks/ and keypoints/ (e.g. the one benchmarks/keypoints_speed.py makes from the real
recording in ../shared/real, or `init --calibration`, `track --backend pose --people 2`, `keypoints`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--out", type=Path, default=Path("docs/keypoints-real.png"))
    ap.add_argument("--frames", default="10,50,90", help="comma-separated frame indices")
    ap.add_argument("--height", type=int, default=420, help="px per panel")
    args = ap.parse_args()
    from mamma_kit.core.io import atomic_path
    from mamma_kit.core.tracks import KeypointTracks, MaskTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.keypoints.pictures import draw_keypoints
    from mamma_kit.masks.pictures import draw_tracks
    from mamma_kit.video import VideoReader

    ws = Workspace(args.workspace)
    cap = ws.load_capture()
    want = [int(f) for f in args.frames.split(",")]
    rows = []
    for c in cap.camera_names:
        mt, kt = MaskTracks.load(ws.mask_file(c)), KeypointTracks.load(ws.keypoints_file(c))
        panels = []
        for i, _, img in VideoReader(cap.cameras[c].video).read_indices(want):
            im = draw_keypoints(draw_tracks(img, mt, i), kt, i)
            panels.append(cv2.resize(im, (im.shape[1] * args.height // im.shape[0], args.height),
                                     interpolation=cv2.INTER_AREA))
        rows.append(np.concatenate(panels, 1))
    width = max(r.shape[1] for r in rows)
    sheet = np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows], 0)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out, ".png") as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"{args.out}: {sheet.shape[1]}x{sheet.shape[0]} px, {len(rows)} cameras x {len(want)} frames")


if __name__ == "__main__":
    main()
