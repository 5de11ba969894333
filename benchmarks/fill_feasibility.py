"""How much of what the tracker misses could feedback from the other views recover? (issue 43's design)

On a rendered capture that `benchmarks/match_accuracy.py --chain` ran (masks/ and keypoints/ from the
videos, the true calibration and clocks), every person-view-frame a camera sees (>= 25 % of the
person's surface landmarks visible, as evaluation.identities.frame_scores counts) but no track covers
(mask IoU >= 0.25, one-to-one per frame) is handed to BlazePose's landmark model as the tracker would
be if the other views told it where the person is. Two places to look, each the box of the points
grown by a quarter:
- ``truth``: the person's true landmarks in that view (an upper bound: a perfect projection);
- ``views``: the person's BlazePose keypoints in the other cameras whose tracks cover them at that
  instant (the nearest frame by the true clocks), triangulated (visibility-weighted DLT) and
  projected into this camera: what a multi-view feedback would have. Which tracks are the person
  comes from the renderer's masks here (the match gives tracked frames their own person 97-99 % of
  the time), so this isolates the looking, not the matching.
The model runs twice (the second time on its own next ROI) with the other tracks' masks blanked.
Counted: misses where it flags a person (>= MIN_FOLLOW_FLAG), and where its mask (segmentation near
its skeleton, others' pixels removed, as the tracker builds it) covers the true person with IoU >=
0.25, i.e. would count as tracked; and the tracked share with those filled.

    nice -n 10 python benchmarks/fill_feasibility.py /work/bench/ident/crowd6_seed0
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

MIN_IOU, MIN_VISIBLE = 0.25, 0.25


def coverage(ws, cam: str):
    """Per gt frame of ``cam``: the pred track column covering each gt person (-1 none), and which
    gt persons the camera sees; with the files they came from."""
    from mamma_kit.core.tracks import LandmarkTracks, MaskTracks
    from mamma_kit.evaluation.identities import camera_pairing
    from mamma_kit.evaluation.masks import pair_frames

    pred, gt = MaskTracks.load(ws.mask_file(cam)), MaskTracks.load(ws.gt_dir / "masks" / f"{cam}.npz")
    e, tg, _, seen_tp, on_tk = camera_pairing(ws, cam, pred, MIN_VISIBLE, MIN_IOU)
    on_tp = np.full(seen_tp.shape, -1, np.int64)  # the track column on each gt person
    t_i, k_i = np.nonzero(on_tk >= 0)
    on_tp[t_i, on_tk[t_i, k_i]] = k_i
    lt = LandmarkTracks.load(ws.gt_dir / "landmarks" / f"{cam}.npz")
    lt_gt = pair_frames(gt.frame_times, lt.frame_times)
    cols = [list(lt.track_ids).index(g) for g in gt.track_ids]
    return {"pred": pred, "gt": gt, "lt": lt, "tg": tg, "lt_gt": lt_gt, "cols": cols, "on": on_tp,
            "seen": seen_tp, "iou": e.iou_tkp}


def roi_of(xy_n2: np.ndarray) -> np.ndarray | None:
    xy = xy_n2[np.isfinite(xy_n2).all(1)]
    if len(xy) < 4:
        return None
    lo, hi = xy.min(0), xy.max(0)
    return np.array([[(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 1.25 * max(hi - lo), 0.0]])


def projected_keypoints(ws, cam: str, t: int, j: int, cov: dict, kts: dict, rig, clocks) -> np.ndarray | None:
    """(33, 2) px in ``cam``: gt person j's BlazePose keypoints in the other cameras' tracks that
    cover them at the same instant, triangulated and projected."""
    from mamma_kit.core.camera import Rig, triangulate_points
    from mamma_kit.core.tracks import nearest_frames

    tau = clocks[cam].to_ref(cov[cam]["gt"].frame_times[t:t + 1])
    xy, w, cams = [], [], []
    for c2, cv in cov.items():
        if c2 == cam:
            continue
        t2 = int(nearest_frames(tau, clocks[c2].to_ref(cv["gt"].frame_times))[0])
        if t2 < 0 or cv["on"][t2, j] < 0 or cv["tg"][t2] < 0:
            continue
        kt = kts[c2]
        k = list(kt.track_ids).index(int(cv["pred"].track_ids[cv["on"][t2, j]]))
        f = int(nearest_frames(cv["pred"].frame_times[cv["tg"][t2]:cv["tg"][t2] + 1], kt.frame_times)[0])
        if f < 0 or not kt.valid[f, k]:
            continue
        xy.append(kt.xy[f, k])
        w.append(np.nan_to_num(kt.visibility[f, k] * kt.presence[f, k]))
        cams.append(rig[c2])
    if len(cams) < 2:
        return None
    X = triangulate_points(Rig(cams), np.stack(xy), np.stack(w))
    ok = np.isfinite(X).all(1)
    if ok.sum() < 8:
        return None
    out = np.full((len(X), 2), np.nan)
    out[ok] = rig[cam].project(X[ok])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("workspace", type=Path)
    args = ap.parse_args()
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import KeypointTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.keypoints.estimator import MIN_FOLLOW_FLAG, PoseEstimator
    from mamma_kit.masks.pose import REACH_SHARE, SEG_THRESHOLD, skeleton_distance
    from mamma_kit.video.reader import VideoReader

    ws = Workspace(args.workspace)
    cap = ws.load_capture()
    rig, _ = read_calibration(ws.calibration)
    clocks, _ = read_timing(ws.timing)
    est = PoseEstimator(1)
    cov = {c: coverage(ws, c) for c in cap.camera_names}
    kts = {c: KeypointTracks.load(ws.keypoints_file(c)) for c in cap.camera_names}
    n_seen = sum(int(cv["seen"].sum()) for cv in cov.values())
    counts = {how: {"tried": 0, "flag": 0, "tracked": 0} for how in ("truth", "views")}
    n_missed = 0
    for c, cv in cov.items():
        miss_tp = cv["seen"] & (cv["on"] < 0)
        if not miss_tp.any():
            continue
        pred, gt, lt, tg = cv["pred"], cv["gt"], cv["lt"], cv["tg"]
        entry = cap.cameras[c]
        rd = VideoReader(entry.video if Path(entry.video).is_absolute() else ws.root / entry.video, entry.rotation)
        W, H = rd.size
        for fi, (_, img) in enumerate(rd.frames()):
            for t in np.flatnonzero(tg == fi):
                for j in np.flatnonzero(miss_tp[t]):
                    n_missed += 1
                    gtm = gt.mask(int(t), int(j))
                    # blank the tracks on other people (not a partial track on this one)
                    others = [pred.mask(fi, k) for k in range(len(pred.track_ids))
                              if pred.present[fi, k] and cv["iou"][t, k, j] < 0.05]
                    keep = ~np.logical_or.reduce(others) if others else None
                    rois = {"truth": roi_of(lt.xy[cv["lt_gt"][t], cv["cols"][j]]),
                            "views": None}
                    xy_proj = projected_keypoints(ws, c, int(t), int(j), cov, kts, rig, clocks)
                    if xy_proj is not None:
                        rois["views"] = roi_of(xy_proj)
                    for how, roi in rois.items():
                        if roi is None:
                            continue
                        counts[how]["tried"] += 1
                        masks = [keep] if keep is not None else None
                        res = est.landmarks(img, roi, masks=masks)
                        res = est.landmarks(img, res.next_rois, masks=masks)
                        if res.score[0] < MIN_FOLLOW_FLAG:
                            continue
                        counts[how]["flag"] += 1
                        prob, (x0, y0) = res.segmentation_of(0, (W, H))
                        if not prob.size:
                            continue
                        box = (x0, y0, x0 + prob.shape[1], y0 + prob.shape[0])
                        m = np.zeros((H, W), bool)
                        near = skeleton_distance(res.xy[0], res.presence[0], box) <= REACH_SHARE * res.rois[0, 2]
                        m[y0:box[3], x0:box[2]] = (prob > SEG_THRESHOLD) & near
                        if keep is not None:
                            m &= keep
                        union = np.count_nonzero(m | gtm)
                        if union and np.count_nonzero(m & gtm) / union >= MIN_IOU:
                            counts[how]["tracked"] += 1
    print(f"{args.workspace.name}: person-view-frames seen {n_seen}, tracked {n_seen - n_missed} "
          f"({100 * (n_seen - n_missed) / n_seen:.1f} %), missed {n_missed}")
    for how, k in counts.items():
        print(f"  ROI from the {how:5s}: tried {k['tried']}, a person flagged {k['flag']}, a mask that counts as "
              f"tracked {k['tracked']} ({100 * k['tracked'] / max(n_missed, 1):.0f} % of the misses); "
              f"tracked with those filled {100 * (n_seen - n_missed + k['tracked']) / n_seen:.1f} %", flush=True)


if __name__ == "__main__":
    main()
