"""Held-out views on a real capture: fit without one camera, then check the fit in that camera.

A real recording has no ground-truth bodies, but every camera is a witness the others do not
see. For each camera c of the capture (default: the two-person recording in shared/real/, with
its Qualisys calibration and one shared clock):

1. a copy of the workspace (hard links) where `mamma-kit match`, `fill` and `fit` use only the
   other cameras (`--cameras` / `--camera-list`), as capture-to-smplx runs them;
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

The hands the same way: the hand model's 21 points of each hand it is sure of in c (keypoints/hands.py)
against the fitted body's hand points (kp_regressor.hand_regressor) and against the other views'
sure hand points triangulated, with PCK at 5 % as well (a hand is about 10 % of the box height).
--fit-hands off fits without the hand points (FitConfig.hand_keypoint_weight 0) for comparison.

    nice -n 10 python benchmarks/heldout_view.py [--root /work/bench/heldout] [--threads 2] [--hands off]
        [--fit-hands off] [--phone rotated|upright]

--people: the cameras' poses refined from the people first (`mamma-kit calibrate WS --people`: a
bundle adjustment on every camera's BlazePose points of the matched people, all four cameras), then
the match again and the held-out fits on that calibration; without it, the calibration as given
(an earlier --people run's refinement is undone first).

--phone rotated: the same on the videos as an upright phone stores them (portrait frames stored
landscape with a display rotation, HEVC Main10 .MOV, AAC, three frames dropped in cam02;
phone_videos); --phone upright: the same copies without the rotation (the encoding's share).
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
HAND_POINTS = 33 + np.arange(42)  # the hands' 21 points each, after the 33 (kp_regressor.stacked)
MIN_VIS = 0.5
MIN_HAND_FLAG = 0.5  # the hand model sure of the hand


def cli(*args) -> None:
    from mamma_kit.cli.app import main

    try:
        main([str(a) for a in args])
    except SystemExit as e:
        if e.code not in (0, None):
            raise RuntimeError(f"mamma-kit {' '.join(map(str, args))} exited with {e.code}") from None


def phone_videos(root: Path, turn: int = 90, crf: int = 18) -> list[Path]:
    """The four videos as an upright phone stores them (issue 41): frames 1920x1080 landscape with a
    display rotation of 90 degrees (``turn`` 0: the same copy stored upright, for the encoding's
    share), HEVC Main10 .MOV, AAC, frames 5, 6 and 13 dropped in cam02; the lab's calibration is at
    the codec-padded 1088 columns; ``crf`` the HEVC quality."""
    from real_workspace import REAL

    from mamma_kit.video.orientation import Orientation
    from mamma_kit.video.phone import phone_copy

    out = []
    for src in sorted((REAL / "videos").glob("cam*.mp4")):
        dst = root / "phone-videos" / f"{src.stem}.MOV"
        if not dst.is_file():
            dst.parent.mkdir(parents=True, exist_ok=True)
            phone_copy(src, dst, orientation=Orientation(turn), crop=(1080, 1920), crf=crf,
                       drop=(5, 6, 13) if src.stem == "cam02" else ())
        out.append(dst)
    return out


def prepare(root: Path, threads: int, hands: str = "auto", phone: str | None = None, crf: int = 18):
    """The real workspace through keypoints, landmarks and the match of all cameras (synced clocks)."""
    turn = {"rotated": 90, "upright": 0}.get(phone or "", None)
    ws = real_workspace(root, stages=True, videos=phone_videos(root, turn, crf) if turn is not None else None)
    if not ws.timing.is_file():
        cli("sync", ws.root, "--method", "synced", "-q")
    cli("landmarks", ws.root, "--hands", hands, "-q")  # one thread per unit, units side by side
    cli("match", ws.root, "-q")
    return ws


def heldout_dir(root: Path, cam: str, fit_hands: bool) -> Path:
    return root / ("heldout" if fit_hands else "heldout-no-hand-points") / cam


def heldout_copy(ws, cam: str, root: Path, fit_hands: bool = True):
    """A hard-linked copy of the workspace for fitting without ``cam``."""
    from mamma_kit.core.workspace import Workspace

    dst = heldout_dir(root, cam, fit_hands)
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(ws.root, dst, copy_function=os.link,
                    ignore=shutil.ignore_patterns("smplx", "report", "fill", "identities.json", "fit-*.json", "match.json",
                                                  "fill.json"))
    return Workspace(dst)


def fitted_points(ws, model, reg) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per fitted person id: (frame_times (T,), points (T, K, 3) of the fitted body by ``reg``)."""
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.core.smplxfile import read_smplx_result

    out = {}
    for f in ws.person_files():
        r = read_smplx_result(f)
        pid = int(f.stem.split("_")[-1])
        verts, _ = pose_mesh_np(model, r.params())
        out[pid] = (r.frame_times, reg.apply(verts))
    return out


def triangulated(rig, others, kts, kt_times_t, idx_of, xy_of, w_of):
    """The other views' points of one person at one time, triangulated (N, 3) (None with < 2 views)."""
    from mamma_kit.core.camera import Rig, triangulate_points
    from mamma_kit.core.tracks import nearest_frames

    best: dict[str, tuple] = {}  # camera -> (weight, xy, w): a view with two tracks of the person
    for c, ot in others:         # at this instant (a fragment beside the whole) gives its surer one
        ko = np.flatnonzero(kts[c].track_ids == ot)
        to = nearest_frames(kt_times_t, kts[c].frame_times)[0] if len(ko) else -1
        if to < 0 or not kts[c].valid[to, ko[0]]:
            continue
        w = w_of(kts[c], to, ko[0])
        if c not in best or float(np.sum(w)) > best[c][0]:
            best[c] = (float(np.sum(w)), xy_of(kts[c], to, ko[0]), w)
    if len(best) < 2:
        return None
    cams = [rig[c] for c in best]
    return triangulate_points(Rig(cams), np.nan_to_num(np.stack([b[1] for b in best.values()])),
                              np.stack([b[2] for b in best.values()]))


def body_xy(kt, t, k):
    return kt.xy[t, k, BODY_POINTS]


def body_w(kt, t, k):
    v = kt.visibility[t, k, BODY_POINTS]
    return np.where(v >= MIN_VIS, v, 0.0)


def hand_xy(kt, t, k):
    return kt.hand_xy[t, k].reshape(42, 2)


def hand_w(kt, t, k):
    sure = (kt.hand_presence[t, k] > MIN_HAND_FLAG) & np.isfinite(kt.hand_xy[t, k]).all((-1, -2))
    return np.repeat(sure.astype(float), 21)


def evaluate_camera(ws, cam: str, root: Path, model, reg, threads: int, reuse: bool = False,
                    fit_hands: bool = True) -> dict:
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.identities import read_identities
    from mamma_kit.core.tracks import KeypointTracks, MaskTracks, nearest_frames

    others = [c for c in ws.load_capture().camera_names if c != cam]
    full = read_identities(ws.identities)
    t0 = time.perf_counter()
    done = heldout_dir(root, cam, fit_hands)
    if reuse and (done / "smplx" / "fit_report.json").is_file():  # a finished held-out fit
        from mamma_kit.core.workspace import Workspace

        hw = Workspace(done)
    else:
        hw = heldout_copy(ws, cam, root, fit_hands)
        cli("match", hw.root, "--cameras", ",".join(others), "--no-plots", "-q")
        cli("fill", hw.root, "-q")  # as capture-to-smplx runs it: what a view lost, from the other two
        cli("fit", hw.root, "--camera-list", ",".join(others), "--threads", threads, "-q",
            *([] if fit_hands else ["--no-hand-points"]))
    fit_s = time.perf_counter() - t0
    held = read_identities(hw.identities)
    rig, _ = read_calibration(ws.calibration)
    cam_c = rig[cam]
    kts = {c: KeypointTracks.load(ws.keypoints_file(c)) for c in [cam, *others]}
    mt = MaskTracks.load(ws.mask_file(cam))
    fits = fitted_points(hw, model, reg)
    err_fit, err_tri, hand_fit, hand_tri = [], [], [], []
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
                box = mt.boxes[t, k]
                h = float(box[3] - box[1])
                if not np.isfinite(h) or h <= 0:
                    continue
                uv_all = cam_c.project(pts_tk3[idx[t]])
                for sel, xy_of, w_of, e_fit, e_tri in ((BODY_POINTS, body_xy, body_w, err_fit, err_tri),
                                                      (HAND_POINTS, hand_xy, hand_w, hand_fit, hand_tri)):
                    seen = w_of(kt, t, k) > 0
                    if not seen.any():
                        continue
                    # the anchor: the other views' detections of this person at this time, triangulated
                    X = triangulated(rig, other_tracks, kts, kt.frame_times[t:t + 1], None, xy_of, w_of)
                    if X is None:
                        continue
                    uv_fit = uv_all[sel]
                    ok = seen & np.isfinite(X).all(1) & np.isfinite(uv_fit).all(1)
                    if not ok.any():
                        continue
                    det = xy_of(kt, t, k)
                    e_fit.append(np.linalg.norm(uv_fit[ok] - det[ok], axis=1) / h)
                    e_tri.append(np.linalg.norm(cam_c.project(X[ok]) - det[ok], axis=1) / h)
    cat = lambda e: np.concatenate(e) if e else np.zeros(0)  # noqa: E731
    ef, et, hf, ht = cat(err_fit), cat(err_tri), cat(hand_fit), cat(hand_tri)
    return {"camera": cam, "points": int(len(ef)), "fit_seconds": round(fit_s, 1), "fit": summary(ef),
            "triangulated": summary(et), "hand_points": int(len(hf)), "hands_fit": summary(hf, 5),
            "hands_triangulated": summary(ht, 5), "_fit": ef, "_tri": et, "_hfit": hf, "_htri": ht}


def summary(e: np.ndarray, *also: int) -> dict:
    """Median (% of the box height) and PCK at 10 % (and at each of ``also`` %)."""
    if not len(e):
        return {"median_pct": None, "pck10": None, **{f"pck{p}": None for p in also}}
    return {"median_pct": round(float(np.median(e)) * 100, 2), "pck10": round(float((e < 0.10).mean()) * 100, 1),
            **{f"pck{p}": round(float((e < p / 100).mean()) * 100, 1) for p in also}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("/work/bench/heldout"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cameras", default=None, help="held-out cameras (default: each in turn)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--reuse", action="store_true", help="evaluate held-out fits already in ROOT/heldout/<cam>")
    ap.add_argument("--hands", default="auto", help="the landmarks' hand refinement: auto (default) or off")
    ap.add_argument("--fit-hands", default="on", choices=("on", "off"), help="the hand model's points in the fit")
    ap.add_argument("--phone", choices=("rotated", "upright"), default=None,
                    help="phone-stored copies (phone_videos): rotated as phones store them, or the same stored upright")
    ap.add_argument("--phone-crf", type=int, default=18, help="the copies' HEVC quality (lower: more bits)")
    ap.add_argument("--people", action="store_true", help="refine the cameras' poses from the people first "
                    "(`calibrate --people`, from the calibration as given, all cameras), then match again")
    a = ap.parse_args()
    from mamma_kit.body.kp_regressor import hand_regressor, keypoint_regressor, stacked
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core import log

    print(f"command: {' '.join(sys.argv)}")
    print(f"load average before: {', '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    t0 = time.perf_counter()
    ws = prepare(a.root, a.threads, a.hands, a.phone, a.phone_crf)
    before = ws.root / "calibration.before-people.toml"
    if before.is_file():  # the calibration as given, whatever an earlier --people run left
        shutil.copyfile(before, ws.calibration)
        before.unlink()
    if a.people:
        cli("calibrate", ws.root, "--people", "-q")
    cli("match", ws.root, "-q")
    log.set_quiet(True)
    model = load_body_model(ws.load_capture().body_model)
    reg = stacked(keypoint_regressor(model), hand_regressor(model))
    cams = a.cameras.split(",") if a.cameras else ws.load_capture().camera_names
    rows = []
    for cam in cams:
        r = evaluate_camera(ws, cam, a.root, model, reg, a.threads, a.reuse, a.fit_hands == "on")
        rows.append(r)
        print(f"held out {cam}: fit {r['fit']['median_pct']} % of box height, PCK@10 {r['fit']['pck10']} %   |   "
              f"triangulated keypoints {r['triangulated']['median_pct']} %, PCK@10 {r['triangulated']['pck10']} %   "
              f"[{r['points']} points, fit {r['fit_seconds']} s]", flush=True)
        print(f"    hands: fit {r['hands_fit']['median_pct']} %, PCK@5 {r['hands_fit']['pck5']} %   |   triangulated "
              f"{r['hands_triangulated']['median_pct']} %, PCK@5 {r['hands_triangulated']['pck5']} %   "
              f"[{r['hand_points']} points]", flush=True)
    ef, et, hf, ht = (np.concatenate([r.pop(k) for r in rows]) for k in ("_fit", "_tri", "_hfit", "_htri"))
    tot = {"fit": summary(ef), "triangulated": summary(et), "points": int(len(ef)),
           "hands_fit": summary(hf, 5), "hands_triangulated": summary(ht, 5), "hand_points": int(len(hf))}
    print(f"all cameras: fit {tot['fit']['median_pct']} % / PCK@10 {tot['fit']['pck10']} %   vs   triangulated "
          f"{tot['triangulated']['median_pct']} % / PCK@10 {tot['triangulated']['pck10']} %   [{tot['points']} points]")
    print(f"all cameras, hands: fit {tot['hands_fit']['median_pct']} % / PCK@5 {tot['hands_fit']['pck5']} % / PCK@10 "
          f"{tot['hands_fit']['pck10']} %   vs   triangulated {tot['hands_triangulated']['median_pct']} % / PCK@5 "
          f"{tot['hands_triangulated']['pck5']} % / PCK@10 {tot['hands_triangulated']['pck10']} %   "
          f"[{tot['hand_points']} points]")
    print(f"total {time.perf_counter() - t0:.0f} s; load average after: {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if a.json:
        a.json.write_text(json.dumps({"cameras": rows, "all": tot}, indent=2))


if __name__ == "__main__":
    main()
