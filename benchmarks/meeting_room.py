"""The meeting-room recording (AV16.3 seq30, ../shared/real/av163-seq30-meeting) end to end from
its raw files, against its real 3D mouth ground truth.

    nice -n 10 python benchmarks/meeting_room.py [--root /work/bench/meeting] [--people 2] [--force]

1. Its calibration, converted: per camera `K`, Bouguet's `kc` (k1, k2, p1, p2) and the pose
   R, t = K^-1 Pmat (scaled to a unit third row; Pmat is the projection of undistorted points).
   Checked against the recording's 2D head annotations (posGT) through the lens model.
2. `mamma-kit init ROOT/ws --videos cam1.avi cam2.avi cam3.avi --calibration ...` (and `--people N`
   when given), then `mamma-kit capture-to-smplx ROOT/ws --to place`: the cameras start at
   different moments, and sync finds their offsets from the audio.
3. Printed: the sync offsets against the timecode difference; per camera the tracks kept; the
   match's persons and the views each holds; per ground-truth person, which fitted persons follow
   it (the nearest fitted mouth within 0.5 m at each ground-truth instant), the share of the
   instants it is followed, and the fitted mouth (the midpoint of BlazePose's two mouth points,
   regressed from the fitted vertices) against MouthGT3D: median and p90 in mm.

Ground-truth times: `Timingcam` gives each frame's timecode (seconds.frame; global frame =
seconds x 25 + frame - 1); MouthGT3D's time t is global frame round(25 t) - 1. The reference
clock is cam1's (its first frame at 0 s).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real" / "av163-seq30-meeting"
CAMS = ("cam1", "cam2", "cam3")
FPS = 25.0
MOUTH = (9, 10)  # BlazePose's mouth_left, mouth_right
FOLLOW_M = 0.5  # a fitted mouth within this of the truth follows that person


def load_mat(cam: str):
    import scipy.io as sio

    return sio.loadmat(REAL / "data" / f"data_av_seq30_{cam}.mat", squeeze_me=True, struct_as_record=False)["Data"]


def global_frames(timing_f2: np.ndarray) -> np.ndarray:
    """(F,) global frame numbers of a camera's frames from its `Timingcam` (seconds.frame)."""
    sec = np.floor(timing_f2[:, 0] + 1e-9)
    return (sec * FPS + np.round((timing_f2[:, 0] - sec) * 100) - 1).astype(int)


def rig_from_mat():
    """The recording's three cameras as a mamma-kit Rig (world-to-camera R, t in metres)."""
    from mamma_kit.core.camera import Camera, Rig

    data = load_mat("cam1")
    cams = []
    for name, c in zip(CAMS, data.cam):
        K_33 = np.asarray(c.K, float)
        M_34 = np.linalg.solve(K_33, np.asarray(c.Pmat, float))
        M_34 /= np.linalg.norm(M_34[2, :3])
        if np.linalg.det(M_34[:, :3]) < 0:
            M_34 = -M_34
        U, _, Vt = np.linalg.svd(M_34[:, :3])  # the nearest rotation: Pmat's 3-digit rounding
        kc = np.asarray(c.kc, float)
        cams.append(Camera(name, (360, 288), K_33, np.r_[kc, 0.0], "radtan", U @ Vt, M_34[:, 3]))
    return Rig(cams)


def truth_mouths() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Reference times (G,) and per person (G, 3) mouth positions of MouthGT3D."""
    data = load_mat("cam1")
    g0 = global_frames(np.asarray(data.Timingcam, float))[0]
    out, times = {}, None
    for p in ("person1", "person2"):
        m = np.asarray(getattr(data.MouthGT3D, p), float)
        t = (np.round(m[:, 0] * FPS).astype(int) - 1 - g0) / FPS
        times = t if times is None else times
        assert np.allclose(times, t), "the two persons' ground truth has different instants"
        out[p] = m[:, 2:5]
    return times, out


def check_calibration(rig) -> dict[str, float]:
    """Median px between MouthGT3D projected through the rig and the 2D head annotations."""
    import cv2

    out = {}
    for cam in CAMS:
        data = load_mat(cam)
        g_cam = global_frames(np.asarray(data.Timingcam, float))
        row_of = {g: k for k, g in enumerate(g_cam)}
        c = rig[cam]
        errs = []
        for p in ("person1", "person2"):
            m = np.asarray(getattr(data.MouthGT3D, p), float)
            pos = np.asarray(getattr(data.posGT, p), float)
            xy, _ = cv2.projectPoints(m[:, 2:5], cv2.Rodrigues(c.R)[0], c.t, c.K, c.dist)
            by_frame = {int(f): r for f, r in zip(pos[:, 0], pos[:, 1:3])}
            for g, q in zip(np.round(m[:, 0] * FPS).astype(int) - 1, xy[:, 0]):
                k = row_of.get(g)
                r = by_frame.get(k + 1) if k is not None else None
                if r is not None and r[0] > 0:
                    errs.append(np.linalg.norm(q - r))
        out[cam] = float(np.median(errs))
    return out


def cli(*args) -> None:
    from mamma_kit.cli.app import main

    try:
        main([str(a) for a in args])
    except SystemExit as e:
        if e.code not in (0, None):
            raise


def fitted_mouths(ws) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per fitted person: frame times (T,) on the reference clock and mouth positions (T, 3)."""
    from mamma_kit.body.kp_regressor import keypoint_regressor
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.smplxfile import read_smplx_result

    model = load_body_model(ws.load_capture().body_model)
    reg = keypoint_regressor(model)
    out = {}
    for f in ws.person_files():
        r = read_smplx_result(f)
        verts, _ = pose_mesh_np(model, r.params())
        out[int(f.stem.split("_")[-1])] = (r.frame_times, reg.apply(verts)[:, list(MOUTH)].mean(axis=1))
    return out


def follow(times_g: np.ndarray, truth_g3: np.ndarray, fits: dict) -> dict:
    """Which fitted persons follow one ground-truth person, and the mouth error where they do."""
    best_id = np.full(len(times_g), -1)
    best_d = np.full(len(times_g), np.inf)
    for pid, (t_f, m_f3) in fits.items():
        k = np.clip(np.searchsorted(t_f, times_g), 1, len(t_f) - 1)
        k = np.where(np.abs(t_f[k - 1] - times_g) < np.abs(t_f[k] - times_g), k - 1, k)
        inside = np.abs(t_f[k] - times_g) < 0.5 / FPS
        d = np.where(inside, np.linalg.norm(m_f3[k] - truth_g3, axis=1), np.inf)
        better = d < best_d
        best_id[better], best_d[better] = pid, d[better]
    followed = best_d < FOLLOW_M
    ids, counts = np.unique(best_id[followed], return_counts=True)
    switches = int(np.sum(np.diff(best_id[followed]) != 0)) if followed.sum() > 1 else 0
    err_mm = best_d[followed] * 1000
    return {"followed_pct": round(100 * float(followed.mean()), 1),
            "by_fitted_person": {int(i): int(c) for i, c in zip(ids, counts)},
            "switches": switches,
            "mouth_median_mm": round(float(np.median(err_mm)), 1) if len(err_mm) else None,
            "mouth_p90_mm": round(float(np.percentile(err_mm, 90)), 1) if len(err_mm) else None,
            "instants": int(len(times_g))}


def track_truth(ws, rig, cam: str, clocks) -> tuple[np.ndarray, ...]:
    """Per frame and track of the camera (the placed ones too), which true person it shows: 0, 1,
    or -1 for neither. A track is on a person when its BlazePose nose lies within a quarter of its
    skeleton's height of that person's projected MouthGT3D, or, where the nose is on neither (a head
    the mask left out) or the track has no keypoints (a placed one), when that person's mouth alone
    lies in the track's box grown by a fifth (a third upwards). Also returned: the track ids, where
    each track has data (T, K), per frame and person whether the recording annotates that person
    inside this camera's image (posGT), i.e. whether the person is to be seen there, and each
    frame's reference time."""
    import cv2

    from mamma_kit.core.filled import load_keypoints, load_masks

    # each view's tracks with those `mamma-kit fill` and `mamma-kit place` added (the placed ones
    # have masks only: their boxes say who they are)
    kt, mt = load_keypoints(ws, cam), load_masks(ws, cam, placed=True)
    times_g, truth = truth_mouths()
    t_ref = clocks[cam].to_ref(kt.frame_times)
    c = rig[cam]
    g = np.clip(np.searchsorted(times_g, t_ref - 0.5 / FPS), 0, len(times_g) - 1)
    near = np.abs(times_g[g] - t_ref) < 0.5 / FPS
    proj = np.stack([cv2.projectPoints(x, cv2.Rodrigues(c.R)[0], c.t, c.K, c.dist)[0][:, 0] for x in truth.values()])
    label = np.full(mt.present.shape, -1)
    present = mt.present.copy()
    kcol = {int(t): k for k, t in enumerate(kt.track_ids)}
    for k, tid in enumerate(mt.track_ids):
        kk = kcol.get(int(tid))
        if kk is not None:
            present[:, k] = kt.valid[:, kk]
        f = np.flatnonzero(present[:, k] & near)
        lab = np.full(len(f), -1)
        if kk is not None:
            nose = kt.xy[f, kk, 0]
            h = np.maximum(np.nanmax(kt.xy[f, kk, :, 1], -1) - np.nanmin(kt.xy[f, kk, :, 1], -1), 60.0)
            d = np.linalg.norm(proj[:, g[f]] - nose[None], axis=-1)  # (2, n)
            best = np.argmin(d, 0)
            lab = np.where(d[best, np.arange(len(f))] < np.maximum(0.25 * h, 15), best, -1)
        b = mt.boxes[f, k]  # (n, 4) x0 y0 x1 y1
        bw, bh = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
        m = proj[:, g[f]]  # (2, n, 2)
        inside = (m[..., 0] > b[:, 0] - 0.1 * bw) & (m[..., 0] < b[:, 2] + 0.1 * bw) & \
                 (m[..., 1] > b[:, 1] - 0.33 * bh) & (m[..., 1] < b[:, 3])
        only = inside.sum(0) == 1
        label[f, k] = np.where(lab >= 0, lab, np.where(only, np.argmax(inside, 0), -1))
    # to be seen: the head annotated inside the image, at an instant with ground truth
    data = load_mat(cam)
    W, H = c.size
    seen = np.zeros((len(kt.frame_times), 2), bool)
    for j, p in enumerate(("person1", "person2")):
        pos = np.asarray(getattr(data.posGT, p), float)
        inside = {int(f) - 1 for f, x, y in pos[:, :3] if 0 < x < W and 0 < y < H}
        seen[:, j] = [k in inside for k in range(len(kt.frame_times))]
    seen &= near[:, None]
    return label, mt.track_ids, present, seen, t_ref


def identity_figures(ws, rig, clocks, ident) -> dict:
    """Per camera: the person-frames the recording annotates that some assigned track follows
    (with the right identity), and tracks or frames on no one."""
    out = {}
    pairs = []  # (fitted person, true person) per assigned, labelled track-frame
    per_cam = {}
    for cam in CAMS:
        label, tids, present, seen, t_ref = track_truth(ws, rig, cam, clocks)
        person = np.where(present, ident.person_frames(cam, tids, t_ref), -1)
        per_cam[cam] = (label, person, seen)
        m = (person >= 0) & (label >= 0)
        pairs += list(zip(person[m], label[m]))
    # one-to-one: each fitted person to the true person it shows most
    from scipy.optimize import linear_sum_assignment

    pids = sorted({int(p) for p, _ in pairs})
    M = np.zeros((len(pids), 2))
    for p, t in pairs:
        M[pids.index(int(p)), int(t)] += 1
    r, c = linear_sum_assignment(-M) if M.size else ([], [])
    to_true = {pids[i]: int(j) for i, j in zip(r, c)}
    for cam, (label, person, seen) in per_cam.items():
        assigned = person >= 0
        true_of = np.full(int(person.max()) + 2, -2)  # fitted person id -> true person (-2: none)
        for p, t in to_true.items():
            true_of[p] = t
        right = assigned & (label >= 0) & (true_of[person] == label)
        followed = np.zeros(seen.shape, bool)
        for k in range(label.shape[1]):
            for j in (0, 1):
                followed[:, j] |= right[:, k] & (label[:, k] == j)
        out[cam] = {"annotated_person_frames": int(seen.sum()),
                    "followed_right_pct": round(100 * float((followed & seen).sum() / max(seen.sum(), 1)), 1),
                    "assigned_track_frames": int(assigned.sum()),
                    "assigned_on_no_one_pct": round(100 * float((assigned & (label < 0)).sum() / max(assigned.sum(), 1)), 1),
                    "assigned_wrong_person_pct": round(100 * float((assigned & (label >= 0) & ~right).sum()
                                                               / max(assigned.sum(), 1)), 1)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("/work/bench/meeting"))
    ap.add_argument("--people", type=int, default=None, help="init --people (default: not given)")
    ap.add_argument("--force", action="store_true", help="recompute every stage")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    ap.add_argument("--to", default="place", help="last stage to run (match: identities only, no mouth figures)")
    a = ap.parse_args()

    from mamma_kit.core import log
    from mamma_kit.core.calibfile import write_calibration
    from mamma_kit.core.filled import load_identities
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.pipeline import init_workspace

    t0 = time.perf_counter()
    rig = rig_from_mat()
    a.root.mkdir(parents=True, exist_ok=True)
    calib = write_calibration(a.root / "av163.calibration.toml", rig,
                              producer={"tool": "benchmarks/meeting_room.py", "from": "AV16.3 Pmat, K, kc"})
    px = check_calibration(rig)
    print("calibration: MouthGT3D projected vs the 2D head annotations, median px: "
          + ", ".join(f"{c} {v:.1f}" for c, v in px.items()))
    ws_path = a.root / "ws"
    if not (ws_path / "capture.toml").is_file():
        log.set_quiet(True)
        init_workspace(ws_path, [REAL / "videos" / f"{c}.avi" for c in CAMS], calibration=calib, people=a.people)
    cli("capture-to-smplx", ws_path, "--to", a.to, "-q", *(["--force"] if a.force else []))
    ws = Workspace(ws_path)

    clocks, _ = read_timing(ws.timing)
    g0 = {c: global_frames(np.asarray(load_mat(c).Timingcam, float))[0] for c in CAMS}
    print("sync (offset of each camera's first frame after cam1's): "
          + ", ".join(f"{c} {1000 * float(clocks[c].to_ref(0.0)):+.0f} ms (timecode {1000 * (g0[c] - g0['cam1']) / FPS:+.0f})"
                      for c in CAMS))
    for c in CAMS:
        mt = MaskTracks.load(ws.mask_file(c))
        frames = [int(n) for n in mt.present.sum(axis=0)]
        print(f"{c}: {len(frames)} tracks kept, frames each {frames}")
    ident = load_identities(ws, placed=True)
    views = {p: ident.views_of(p) for p in ident.person_ids}
    print(f"match: {len(views)} persons; views per person: " + "; ".join(f"{p}: {','.join(v)}" for p, v in views.items()))

    idf = identity_figures(ws, rig, clocks, ident)
    print("| camera | person-frames the recording annotates | followed with the right identity % | "
          "assigned track-frames | on no one % | on the wrong person % |")
    print("|---|---:|---:|---:|---:|---:|")
    for c, r in idf.items():
        print(f"| {c} | {r['annotated_person_frames']} | {r['followed_right_pct']} | {r['assigned_track_frames']} | "
              f"{r['assigned_on_no_one_pct']} | {r['assigned_wrong_person_pct']} |")
    if a.to not in ("fit", "place"):
        print(f"total {time.perf_counter() - t0:.0f} s")
        return
    times_g, truth = truth_mouths()
    fits = fitted_mouths(ws)
    rows = {p: follow(times_g, x, fits) for p, x in truth.items()}
    print(f"fit: {len(fits)} persons")
    print("| ground truth | followed (% of instants) | by fitted persons (instants) | switches | mouth median mm | mouth p90 mm |")
    print("|---|---:|---|---:|---:|---:|")
    for p, r in rows.items():
        by = ", ".join(f"{k}: {v}" for k, v in r["by_fitted_person"].items()) or "none"
        print(f"| {p} | {r['followed_pct']} | {by} | {r['switches']} | {r['mouth_median_mm']} | {r['mouth_p90_mm']} |")
    print(f"total {time.perf_counter() - t0:.0f} s")
    if a.json:
        a.json.write_text(json.dumps({"calibration_px": px, "persons_matched": len(views), "views": views,
                                      "identities": idf, "fitted": len(fits), "truth": rows}, indent=1))


if __name__ == "__main__":
    main()
