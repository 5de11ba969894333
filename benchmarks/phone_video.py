"""Phone files on real footage (issue 41): portrait storage, HLG HDR and 4K against the originals.

    .venv/bin/python benchmarks/phone_video.py --root /tmp/phone [--frames 40] [--parts rotated,hlg,4k]

Every copy is made with mamma_kit.video.phone.phone_copy from a recording in ../shared/real:

rotated  pose2sim-multiperson's four cameras (1088x1920 portrait H.264, 60 fps) as an upright
         phone stores them: frames 1920x1080 landscape with a display rotation of 90 degrees, HEVC
         Main10 .MOV, AAC, three frames dropped in cam02, the lab's 1088-column calibration
         (codec padding). `track --backend pose --people 2` and `keypoints` on both: tracks per
         view, and the copy's keypoints against the original's (median, % of the person's height).
hlg      the same cameras as HLG BT.2020 10-bit (the SDR picture mapped to HLG, colour.sdr_to_hlg),
         and as SDR HEVC Main10 (the cost of a second encoding alone): keypoints against the SDR
         original's; and caliscope-charuco_calibration's cam_0 board video (1280x720) as HLG:
         ChArUco corners against the original's on the frames both find.
4k       pose2sim cam01 scaled to 2160x3840 (HEVC) against a 1080x1920 HEVC copy: seconds per
         frame of decoding, of the pose tracker and of keypoints (per person-frame).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_workspace import REAL  # noqa: E402

SHARED = REAL.parent
CAMS = ("cam01", "cam02", "cam03", "cam04")
BODY = np.r_[0, 11:33]


def workspace(root: Path, videos: list[Path], calibration: Path | None = REAL / "calibration" / "Calib.qca.txt"):
    from mamma_kit.cli.app import main as cli
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.pipeline import init_workspace

    if not (root / "capture.toml").is_file():
        init_workspace(root, videos, calibration=calibration, people=2)
    for cmd in (["track", str(root), "--backend", "pose", "--people", "2"], ["keypoints", str(root)]):
        try:
            cli([*cmd, "--quiet"])
        except SystemExit as e:
            if e.code not in (0, None):
                raise
    return Workspace(root)


def keypoint_errors(ref, ws, cam: str) -> np.ndarray:
    """Body keypoints of ``ws`` against ``ref`` (same instants, same person by the nearest box), in %
    of the person's box height, where both see the point."""
    from mamma_kit.core.tracks import KeypointTracks, MaskTracks, nearest_frames

    a_mt, b_mt = MaskTracks.load(ref.mask_file(cam)), MaskTracks.load(ws.mask_file(cam))
    a, b = KeypointTracks.load(ref.keypoints_file(cam)), KeypointTracks.load(ws.keypoints_file(cam))
    ia = nearest_frames(b.frame_times, a.frame_times)
    errs = []
    for tb, ta in enumerate(ia):
        if ta < 0:
            continue
        for kb in np.flatnonzero(b.valid[tb]):
            cb = b_mt.boxes[tb, kb].reshape(2, 2).mean(0)
            d = [np.linalg.norm(a_mt.boxes[ta, k].reshape(2, 2).mean(0) - cb) if a_mt.present[ta, k] else np.inf
                 for k in range(len(a_mt.track_ids))]
            ka = int(np.argmin(d))
            if not np.isfinite(d[ka]) or not a.valid[ta, ka]:
                continue
            h = a_mt.boxes[ta, ka, 3] - a_mt.boxes[ta, ka, 1]
            if d[ka] > 0.1 * h:  # the original did not track this person in this frame
                continue
            vis = (a.visibility[ta, ka, BODY] > 0.5) & (b.visibility[tb, kb, BODY] > 0.5)
            errs += list(np.linalg.norm(a.xy[ta, ka, BODY] - b.xy[tb, kb, BODY], axis=1)[vis] / h * 100)
    return np.asarray(errs)


def clips(root: Path, frames: int) -> list[Path]:
    """The first ``frames`` of each pose2sim camera, H.264 as recorded (the reference)."""
    from mamma_kit.video.phone import phone_copy
    from mamma_kit.video.orientation import Orientation

    out = []
    for c in CAMS:
        p = root / "original" / f"{c}.mp4"
        if not p.is_file():
            p.parent.mkdir(parents=True, exist_ok=True)
            phone_copy(REAL / "videos" / f"{c}.mp4", p, orientation=Orientation(), codec="h264", bit_depth=8,
                       frames=frames, crf=12, audio=False)
        out.append(p)
    return out


def compare(name: str, ref, ws) -> None:
    from mamma_kit.core.tracks import MaskTracks

    for c in CAMS:
        e = keypoint_errors(ref, ws, c)
        ma, mb = MaskTracks.load(ref.mask_file(c)), MaskTracks.load(ws.mask_file(c))
        print(f"| {name} | {c} | {len(ma.track_ids)} / {len(mb.track_ids)} | {int(ma.present.sum())} / "
              f"{int(mb.present.sum())} | {len(e)} | {np.median(e):.2f} | {np.percentile(e, 95):.2f} |", flush=True)


def part_rotated(root: Path, ref, frames: int) -> None:
    from mamma_kit.video.orientation import Orientation
    from mamma_kit.video.phone import phone_copy

    vids = []
    for c in CAMS:
        p = root / "rotated" / f"{c}.MOV"
        if not p.is_file():
            p.parent.mkdir(parents=True, exist_ok=True)
            phone_copy(REAL / "videos" / f"{c}.mp4", p, orientation=Orientation(90), crop=(1080, 1920),
                       frames=frames, drop=(5, 6, 13) if c == "cam02" else ())
        vids.append(p)
    compare("portrait stored landscape + rotation 90, HEVC Main10 .MOV, AAC, padded calibration", ref,
            workspace(root / "rotated" / "ws", vids))


def part_hlg(root: Path, ref, frames: int) -> None:
    from mamma_kit.video.orientation import Orientation
    from mamma_kit.video.phone import phone_copy

    for name, hlg in (("SDR HEVC Main10 (a second encoding alone)", False), ("HLG BT.2020 HEVC Main10", True)):
        sub = "hlg" if hlg else "sdr10"
        vids = []
        for c in CAMS:
            p = root / sub / f"{c}.mov"
            if not p.is_file():
                p.parent.mkdir(parents=True, exist_ok=True)
                phone_copy(REAL / "videos" / f"{c}.mp4", p, orientation=Orientation(), hlg=hlg, frames=frames,
                           audio=False)
            vids.append(p)
        compare(name, ref, workspace(root / sub / "ws", vids))
    # the board: ChArUco corners in a real calibration video and in its HLG copy
    from mamma_kit.calibration.board import load_board_spec
    from mamma_kit.calibration.detect import detect_video

    folder = SHARED / "caliscope-charuco_calibration"
    spec = load_board_spec(folder / "charuco.toml")
    src = folder / "videos" / "cam_0.mp4"
    print("\n| board video cam_0 (1280x720) | frames | corners both find | median px | 95th pct px | max px |\n"
          "|---|---|---|---|---|---|")
    det0 = detect_video(src, spec, "cam_0", max_fps=None, progress=False)
    for name, hlg in (("SDR HEVC Main10", False), ("HLG BT.2020 HEVC Main10", True)):
        p = root / "board" / f"cam_0-{'hlg' if hlg else 'sdr10'}.mov"
        if not p.is_file():
            p.parent.mkdir(parents=True, exist_ok=True)
            phone_copy(src, p, orientation=Orientation(), hlg=hlg, audio=False)
        det = detect_video(p, spec, "cam_0", max_fps=None, progress=False)
        n = min(len(det0.times_f), len(det.times_f))
        d = np.linalg.norm(det0.xy_fn2[:n] - det.xy_fn2[:n], axis=-1)
        d = d[np.isfinite(d)]
        print(f"| {name} | {n} | {len(d)} (of {int(np.isfinite(det0.xy_fn2[:n, :, 0]).sum())} in the original) | "
              f"{np.median(d):.3f} | {np.percentile(d, 95):.3f} | {d.max():.3f} |", flush=True)


def part_4k(root: Path, frames: int) -> None:
    import cv2

    from mamma_kit.keypoints.estimator import PoseEstimator
    from mamma_kit.keypoints.stage import keypoints_for_tracks
    from mamma_kit.masks.base import CameraInput
    from mamma_kit.masks.pose import PoseBackend
    from mamma_kit.video import VideoReader
    from mamma_kit.video.writer import VideoWriter

    src = VideoReader(REAL / "videos" / "cam01.mp4")
    print(f"\nload average before: {', '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores\n"
          "\n| size (HEVC 8-bit) | decode ms/frame | pose tracker ms/frame | keypoints ms/person-frame | "
          "keypoints against 1080x1920 (median % of box) |\n|---|---|---|---|---|")
    est = PoseEstimator(2)
    first = None
    for w, h in ((1080, 1920), (2160, 3840)):
        p = root / "4k" / f"cam01-{w}x{h}.mp4"
        if not p.is_file():
            p.parent.mkdir(parents=True, exist_ok=True)
            with VideoWriter(p, w, h, fps=60, codec="hevc", crf=20, preset="ultrafast") as wr:
                for i, (t, rgb) in enumerate(src.frames()):
                    if i >= frames:
                        break
                    wr.write_frame(cv2.resize(rgb[:1920, :1080], (w, h), interpolation=cv2.INTER_CUBIC), t)
        rd = VideoReader(p)
        t0 = time.perf_counter()
        n = sum(1 for _ in rd.frames())
        dec = (time.perf_counter() - t0) / n
        t0 = time.perf_counter()
        mt, _ = PoseBackend().track_camera(CameraInput("cam01", p, p.parent))
        trk = (time.perf_counter() - t0) / n
        t0 = time.perf_counter()
        kt, summ = keypoints_for_tracks(est, mt, p)
        kp = (time.perf_counter() - t0) / max(int(mt.present.sum()), 1)
        agree = "-"
        if first is None:
            first = (w, mt, kt)
        else:  # the same person (nearest box) in the two sizes, points in the smaller one's pixels
            s = first[0] / w
            errs = []
            for t in range(min(len(first[1].frame_times), len(mt.frame_times))):
                for k in np.flatnonzero(first[2].valid[t]):
                    c = first[1].boxes[t, k].reshape(2, 2).mean(0)
                    hh = first[1].boxes[t, k, 3] - first[1].boxes[t, k, 1]
                    d = [np.linalg.norm(mt.boxes[t, j].reshape(2, 2).mean(0) * s - c) if kt.valid[t, j] else np.inf
                         for j in range(len(mt.track_ids))]
                    j = int(np.argmin(d)) if d else -1
                    if j < 0 or d[j] > 0.1 * hh:
                        continue
                    vis = (first[2].visibility[t, k, BODY] > 0.5) & (kt.visibility[t, j, BODY] > 0.5)
                    errs += list(np.linalg.norm(first[2].xy[t, k, BODY] - kt.xy[t, j, BODY] * s, axis=1)[vis] / hh * 100)
            agree = f"{np.median(errs):.2f} ({len(errs)} points)"
        print(f"| {w}x{h} | {dec * 1e3:.0f} | {trk * 1e3:.0f} | {kp * 1e3:.0f} | {agree} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("/work/bench/phone"))
    ap.add_argument("--frames", type=int, default=40, help="frames of each pose2sim camera")
    ap.add_argument("--parts", default="rotated,hlg,4k")
    args = ap.parse_args()
    from mamma_kit.core import log
    from mamma_kit.core.reproducible import configure

    configure()
    log.set_quiet(True)
    parts = args.parts.split(",")
    if {"rotated", "hlg"} & set(parts):
        ref = workspace(args.root / "original" / "ws", clips(args.root, args.frames))
        print(f"pose2sim-multiperson, first {args.frames} frames of each camera; keypoints (nose, shoulders to feet, "
              f"visibility > 0.5 in both) against the original's, in % of the person's box height\n\n"
              f"| copy | camera | tracks original / copy | person-frames original / copy | points | median % | "
              f"95th pct % |\n|---|---|---|---|---|---|---|")
        if "rotated" in parts:
            part_rotated(args.root, ref, args.frames)
        if "hlg" in parts:
            part_hlg(args.root, ref, args.frames)
    if "4k" in parts:
        part_4k(args.root, min(args.frames, 30))


if __name__ == "__main__":
    main()
