"""Held-out views on a real capture: fit without one camera, then check the fit in that camera.

A real recording has no ground-truth bodies, but every camera is a witness the others do not
see. For each camera c of the capture (default: the two-person recording in shared/real/, with
its Qualisys calibration and one shared clock):

1. a copy of the workspace (hard links) where `mamma-kit match` and `mamma-kit fit` use only the
   other cameras (`--cameras` / `--camera-list`);
2. the fitted bodies' 33 BlazePose points (the fit's keypoint regressor applied to the fitted
   vertices) projected into c, against BlazePose's own detections in c for the same person (c's
   tracks are tied to persons by the match of all cameras);
3. the anchor to beat: the other cameras' BlazePose points of that person triangulated per frame
   (visibility-weighted DLT, core.camera.triangulate_points) and projected into c.

Printed per held-out camera and over all: the median error in % of the person's box height in c
(from c's mask track) and PCK at 10 % of it, over the body points (nose, shoulders to feet: 23 of
the 33, the face's ten points would weigh the nose ten times) that BlazePose sees in c
(visibility >= 0.5) and that both the fit and the triangulation give. BlazePose in c is itself a
few % off the truth, so both figures include its error; only their difference is the method's.

    nice -n 10 python benchmarks/heldout_view.py [--root /work/bench/heldout] [--threads 2] [--hands off]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_workspace import real_workspace  # noqa: E402

BODY_POINTS = np.r_[0, 11:33]
MIN_VIS = 0.5


def cli(*args) -> None:
    from mamma_kit.cli.app import main

    try:
        main([str(a) for a in args])
    except SystemExit as e:
        if e.code not in (0, None):
            raise RuntimeError(f"mamma-kit {' '.join(map(str, args))} exited with {e.code}") from None


def prepare(root: Path, threads: int, hands: str = "auto"):
    """The real workspace through keypoints, landmarks and the match of all cameras (synced clocks)."""
    ws = real_workspace(root, stages=True)
    if not ws.timing.is_file():
        cli("sync", ws.root, "--method", "synced", "-q")
    cli("landmarks", ws.root, "--threads", threads, "--hands", hands, "-q")
    cli("match", ws.root, "-q")
    return ws


def heldout_copy(ws, cam: str, root: Path):
    """A hard-linked copy of the workspace for fitting without ``cam``."""
    from mamma_kit.core.workspace import Workspace

    dst = root / "heldout" / cam
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(ws.root, dst, copy_function=os.link,
                    ignore=shutil.ignore_patterns("smplx", "report", "identities.json", "fit-*.json", "match.json"))
    return Workspace(dst)


def fitted_points(ws, model, reg) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per fitted person id: (frame_times (T,), BlazePose points (T, 33, 3) of the fitted body)."""
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.core.smplxfile import read_smplx_result

    out = {}
    for f in ws.person_files():
        r = read_smplx_result(f)
        pid = int(f.stem.split("_")[-1])
        verts, _ = pose_mesh_np(model, r.params())
        out[pid] = (r.frame_times, reg.apply(verts))
    return out


def evaluate_camera(ws, cam: str, root: Path, model, reg, threads: int, reuse: bool = False) -> dict:
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.camera import Rig, triangulate_points
    from mamma_kit.core.identities import read_identities
    from mamma_kit.core.tracks import KeypointTracks, MaskTracks, nearest_frames

    others = [c for c in ws.load_capture().camera_names if c != cam]
    full = read_identities(ws.identities)
    t0 = time.perf_counter()
    done = root / "heldout" / cam
    if reuse and (done / "smplx" / "fit_report.json").is_file():  # a finished held-out fit
        from mamma_kit.core.workspace import Workspace

        hw = Workspace(done)
    else:
        hw = heldout_copy(ws, cam, root)
        cli("match", hw.root, "--cameras", ",".join(others), "--no-plots", "-q")
        cli("fit", hw.root, "--camera-list", ",".join(others), "--threads", threads, "-q")
    fit_s = time.perf_counter() - t0
    held = read_identities(hw.identities)
    rig, _ = read_calibration(ws.calibration)
    cam_c = rig[cam]
    kts = {c: KeypointTracks.load(ws.keypoints_file(c)) for c in [cam, *others]}
    mt = MaskTracks.load(ws.mask_file(cam))
    fits = fitted_points(hw, model, reg)
    err_fit, err_tri = [], []
    for pid, (times, pts_tk3) in fits.items():
        # the held-out match's person -> the full match's person (its tracks) -> its tracks in cam
        full_ids = {full.person_of(c, t) for c, t in held.tracks_of(pid)} - {None}
        if len(full_ids) != 1:
            continue
        full_pid = full_ids.pop()
        mine = [t for c, t in full.tracks_of(full_pid) if c == cam]
        other_tracks = [(c, t) for c, t in full.tracks_of(full_pid) if c != cam]
        for tid in mine:
            k = int(np.flatnonzero(kts[cam].track_ids == tid)[0])
            kt = kts[cam]
            idx = nearest_frames(kt.frame_times, times)  # cam's frames -> fitted frames
            for t in np.flatnonzero(kt.valid[:, k] & (idx >= 0)):
                det = kt.xy[t, k, BODY_POINTS]
                vis = kt.visibility[t, k, BODY_POINTS] >= MIN_VIS
                box = mt.boxes[t, k]
                h = float(box[3] - box[1])
                if not vis.any() or not np.isfinite(h) or h <= 0:
                    continue
                uv_fit = cam_c.project(pts_tk3[idx[t]][BODY_POINTS])
                # the anchor: the other views' detections of this person at this time, triangulated
                xy_c, w_c, cams = [], [], []
                for c, ot in other_tracks:
                    ko = np.flatnonzero(kts[c].track_ids == ot)
                    to = nearest_frames(kt.frame_times[t:t + 1], kts[c].frame_times)[0] if len(ko) else -1
                    if to < 0 or not kts[c].valid[to, ko[0]]:
                        continue
                    xy_c.append(kts[c].xy[to, ko[0], BODY_POINTS])
                    w_c.append(np.where(kts[c].visibility[to, ko[0], BODY_POINTS] >= MIN_VIS,
                                        kts[c].visibility[to, ko[0], BODY_POINTS], 0.0))
                    cams.append(rig[c])
                if len(cams) < 2:
                    continue
                X = triangulate_points(Rig(cams), np.stack(xy_c), np.stack(w_c))
                ok = vis & np.isfinite(X).all(1) & np.isfinite(uv_fit).all(1)
                if not ok.any():
                    continue
                uv_tri = cam_c.project(X[ok])
                err_fit.append(np.linalg.norm(uv_fit[ok] - det[ok], axis=1) / h)
                err_tri.append(np.linalg.norm(uv_tri - det[ok], axis=1) / h)
    ef = np.concatenate(err_fit) if err_fit else np.zeros(0)
    et = np.concatenate(err_tri) if err_tri else np.zeros(0)
    return {"camera": cam, "points": int(len(ef)), "fit_seconds": round(fit_s, 1), "fit": summary(ef),
            "triangulated": summary(et), "_fit": ef, "_tri": et}


def summary(e: np.ndarray) -> dict:
    if not len(e):
        return {"median_pct": None, "pck10": None}
    return {"median_pct": round(float(np.median(e)) * 100, 2), "pck10": round(float((e < 0.10).mean()) * 100, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("/work/bench/heldout"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cameras", default=None, help="held-out cameras (default: each in turn)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--reuse", action="store_true", help="evaluate held-out fits already in ROOT/heldout/<cam>")
    ap.add_argument("--hands", default="auto", help="the landmarks' hand refinement: auto (default) or off")
    a = ap.parse_args()
    from mamma_kit.body.kp_regressor import keypoint_regressor
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core import log

    print(f"command: {' '.join(sys.argv)}")
    print(f"load average before: {', '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    t0 = time.perf_counter()
    ws = prepare(a.root, a.threads, a.hands)
    log.set_quiet(True)
    model = load_body_model(ws.load_capture().body_model)
    reg = keypoint_regressor(model)
    cams = a.cameras.split(",") if a.cameras else ws.load_capture().camera_names
    rows = []
    for cam in cams:
        r = evaluate_camera(ws, cam, a.root, model, reg, a.threads, a.reuse)
        rows.append(r)
        print(f"held out {cam}: fit {r['fit']['median_pct']} % of box height, PCK@10 {r['fit']['pck10']} %   |   "
              f"triangulated keypoints {r['triangulated']['median_pct']} %, PCK@10 {r['triangulated']['pck10']} %   "
              f"[{r['points']} points, fit {r['fit_seconds']} s]", flush=True)
    ef = np.concatenate([r.pop("_fit") for r in rows])
    et = np.concatenate([r.pop("_tri") for r in rows])
    tot = {"fit": summary(ef), "triangulated": summary(et), "points": int(len(ef))}
    print(f"all cameras: fit {tot['fit']['median_pct']} % / PCK@10 {tot['fit']['pck10']} %   vs   triangulated "
          f"{tot['triangulated']['median_pct']} % / PCK@10 {tot['triangulated']['pck10']} %   [{tot['points']} points]")
    print(f"total {time.perf_counter() - t0:.0f} s; load average after: {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if a.json:
        a.json.write_text(json.dumps({"cameras": rows, "all": tot}, indent=2))


if __name__ == "__main__":
    main()
