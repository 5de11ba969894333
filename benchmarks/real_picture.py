"""The README's picture: a real capture with its fitted bodies, one frame from each camera.

    nice -n 10 python benchmarks/real_picture.py [--root /work/bench/picture] [--out docs/real-capture.jpg]

Runs `capture-to-smplx --to fit` on the two-person recording in ../shared/real (its Qualisys
calibration, one shared clock; cached in ROOT/ws), then draws the fitted meshes over the first fitted frame
of every camera (the report's own overlay drawing) side by side.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_workspace import real_workspace  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("/work/bench/picture"))
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "real-capture.jpg")
    ap.add_argument("--height", type=int, default=480, help="height of each camera's tile (px)")
    args = ap.parse_args()

    from mamma_kit.cli.app import main as cli
    from mamma_kit.report.data import ReportData
    from mamma_kit.report.overlays import overlay_cameras, overlay_stills

    ws = real_workspace(args.root)
    try:
        cli(["capture-to-smplx", str(ws.root), "--to", "fit", "--quiet"])
    except SystemExit as e:
        if e.code not in (0, None):
            raise
    data = ReportData(ws)
    cams, notes = overlay_cameras(data)
    if notes:
        print("\n".join(notes))
    tiles = []
    with tempfile.TemporaryDirectory() as tmp:
        for cam in cams:
            w, h = data.rig[cam].size
            width = int(round(args.height * w / h))
            still = overlay_stills(data, cam, Path(tmp) / f"{cam}.png", n=1, width=width)
            if still is None:
                continue
            tiles.append(cv2.imread(str(still[0])))
    if not tiles:
        raise SystemExit("no camera shows a fitted body")
    h = min(t.shape[0] for t in tiles)
    row = np.concatenate([t[:h] for t in tiles], axis=1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), row, [cv2.IMWRITE_JPEG_QUALITY, 90, cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {args.out} ({row.shape[1]}x{row.shape[0]}, {len(tiles)} cameras, {len(data.people)} people)")


if __name__ == "__main__":
    main()
