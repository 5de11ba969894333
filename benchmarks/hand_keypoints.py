"""MediaPipe's hand landmarker (keypoints/hands.py) on BlazePose's hands: synthetic against the truth,
and on the real recording in shared/real/.

    python benchmarks/hand_keypoints.py [--synthetic /work/tmp/demo5] [--real-root /work/bench/real]
        [--every 3] [--picture hands.png]

--synthetic: a workspace with ground truth and keypoints/<cam>.npz (e.g. `mamma-kit demo --out DIR`);
each hand BlazePose found (wrist within 15 % of the box height of a true wrist) is read by the hand
landmarker and its wrist and 15 finger joints are compared with the true SMPL-X joints projected
with the true calibration and clocks, in % of the person's box height (the joints' extent x 1.2).
--real-root: the real recording's workspace (benchmarks/real_workspace.py: pose tracks, keypoints),
where there is no truth: the share of hands the model is sure of, and --picture shows some of them.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

# MediaPipe's points that have an SMPL-X joint: wrist, then thumb CMC, MCP, IP, index / middle / ring /
# pinky MCP, PIP, DIP; SMPL-X's left hand joints 25-39 are index, middle, pinky, ring, thumb (3 each)
MP_POINTS = [0, 1, 2, 3, 5, 6, 7, 9, 10, 11, 13, 14, 15, 17, 18, 19]


def smplx_joints(side: int) -> list[int]:
    return [20 + side] + [b + 15 * side + k for b in (37, 25, 28, 34, 31) for k in range(3)]


def hands_of_frame(hl, img, kt, t):
    """{(track column, side): (21 points (21, 2) px, the model's hand flag, the ROI (4,))} for every
    valid person of frame t."""
    from mamma_kit.keypoints.hands import hand_rois

    ks = np.flatnonzero(kt.valid[t])
    out = {}
    for side in (0, 1):
        rois = hand_rois(kt.xy[t, ks], side)
        res = hl.landmarks(img, rois)
        for r, k in enumerate(ks):
            out[(int(k), side)] = (res.xy[r], float(res.presence[r]), rois[r])
    return out


def synthetic(ws_path: Path, hl, every: int) -> dict:
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import KeypointTracks, nearest_frames
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.keypoints.hands import MIN_PRESENCE
    from mamma_kit.video import VideoReader

    ws = Workspace(ws_path)
    rig, _ = read_calibration(ws.gt_dir / "calibration.toml")
    clocks, _ = read_timing(ws.gt_dir / "timing.toml")
    gts = [np.load(p) for p in sorted((ws.gt_dir / "smplx").glob("person_*.npz"))]
    cap = ws.load_capture()
    wrist_bp, errs, presence = [], [], []
    for cam in cap.camera_names:
        kt = KeypointTracks.load(ws.keypoints_file(cam))
        # each true body's sample at each of the camera's frames (scene clock), -1 where none is near
        at = [nearest_frames(clocks[cam].to_ref(kt.frame_times), g["frame_times"], tol=0.02) for g in gts]
        for t, (_, img) in enumerate(VideoReader(cap.cameras[cam].video).frames()):
            if t >= len(kt.frame_times):
                break
            if t % every:
                continue
            truth = [rig[cam].project(g["joints"][i[t]]) for g, i in zip(gts, at) if i[t] >= 0]
            if not truth:
                continue
            for (k, side), (xy, pres, _) in hands_of_frame(hl, img, kt, t).items():
                w = kt.xy[t, k, 15 + side]
                J = min(truth, key=lambda j: np.linalg.norm(j[20 + side] - w))
                box_h = np.ptp(J[:, 1]) * 1.2
                if not np.isfinite(xy).all() or np.linalg.norm(J[20 + side] - w) > 0.15 * box_h:
                    continue
                wrist_bp.append(np.linalg.norm(w - J[20 + side]) / box_h)
                errs.append(np.linalg.norm(xy[MP_POINTS] - J[smplx_joints(side)], axis=1) / box_h)
                presence.append(pres)
    E, P = 100 * np.array(errs), np.array(presence)
    sure = P > MIN_PRESENCE
    return {"hands": len(P), "sure": float(sure.mean()), "blazepose_wrist": float(np.median(wrist_bp) * 100),
            "wrist": float(np.median(E[:, 0])), "fingers": float(np.median(E[:, 1:])),
            "wrist_sure": float(np.median(E[sure, 0])) if sure.any() else None,
            "fingers_sure": float(np.median(E[sure, 1:])) if sure.any() else None}


def real(root: Path, hl, every: int, picture: Path | None) -> dict:
    import cv2

    from mamma_kit.core.tracks import KeypointTracks
    from mamma_kit.keypoints import blazepose as bp
    from mamma_kit.keypoints.hands import MIN_PRESENCE
    from mamma_kit.video import VideoReader
    from real_workspace import real_workspace

    ws = real_workspace(root, stages=True)
    cap = ws.load_capture()
    presence, sides, shots = [], [], []
    for cam in cap.camera_names:
        kt = KeypointTracks.load(ws.keypoints_file(cam))
        for t, (_, img) in enumerate(VideoReader(cap.cameras[cam].video).frames()):
            if t >= len(kt.frame_times) or t % every:
                continue
            for (k, side), (xy, pres, roi) in hands_of_frame(hl, img, kt, t).items():
                if not np.isfinite(roi).all() or kt.visibility[t, k, 15 + side] < 0.5:
                    continue
                presence.append(pres)
                sides.append(roi[2])
                if picture is not None and len(shots) < 12 and t % 30 == 0:
                    crop, A = bp.crop_roi(img, roi, 160)
                    c8 = (crop * 255).astype(np.uint8).copy()
                    for q in bp.apply_affine(A, xy):
                        cv2.circle(c8, (int(q[0]), int(q[1])), 2, (0, 255, 0) if pres > MIN_PRESENCE else (255, 0, 0), -1)
                    shots.append(c8)
    if picture is not None and shots:
        cv2.imwrite(str(picture), cv2.cvtColor(np.hstack(shots), cv2.COLOR_RGB2BGR))
    P = np.array(presence)
    return {"hands": len(P), "sure": float((P > MIN_PRESENCE).mean()), "roi_side_px": float(np.median(sides))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--synthetic", type=Path)
    ap.add_argument("--real-root", type=Path)
    ap.add_argument("--every", type=int, default=1, help="every n-th frame")
    ap.add_argument("--picture", type=Path)
    a = ap.parse_args()
    from mamma_kit.keypoints.hands import HandLandmarker

    hl = HandLandmarker()
    if a.synthetic:
        t0 = time.perf_counter()
        s = synthetic(a.synthetic, hl, a.every)
        f = lambda v: "n/a" if v is None else f"{v:.2f}"
        print(f"synthetic {a.synthetic}: {s['hands']} hands in {time.perf_counter() - t0:.0f} s; the model is sure "
              f"(presence > 0.5) of {100 * s['sure']:.0f} %; median error, % of the box height: BlazePose's wrist "
              f"{s['blazepose_wrist']:.2f}; the landmarker's wrist {s['wrist']:.2f}, finger joints {s['fingers']:.2f}; "
              f"where it is sure: wrist {f(s['wrist_sure'])}, finger joints {f(s['fingers_sure'])}")
    if a.real_root:
        t0 = time.perf_counter()
        r = real(a.real_root, hl, a.every, a.picture)
        print(f"real recording: {r['hands']} hands BlazePose sees in {time.perf_counter() - t0:.0f} s; the model "
              f"is sure of {100 * r['sure']:.0f} % (median ROI side {r['roi_side_px']:.0f} px)"
              + (f"; picture {a.picture}" if a.picture else ""))


if __name__ == "__main__":
    main()
