"""How many of a crowd's hidden people the fitted bodies could place in the views that lost them.

On a synthetic capture that went through the chain (`benchmarks/match_accuracy.py --chain` and then
`mamma-kit fit`), the person-view-frames the identity score counts as seen (a camera, a frame, a
person with at least 25 % of the surface landmarks visible: evaluation.identities.camera_pairing)
that no track covers are mostly people behind others, where the image shows too little of them for
BlazePose (or the fill) to find a body. The fitted bodies know where they are: each body's
silhouette in the camera, z-buffered against the others' (vertices splatted, closed), is the part of
it that camera sees. Printed per capture: the seen person-view-frames no track covers, how many a
fitted body's visible silhouette overlaps at IoU >= 0.25 (what the score needs), and how many of
those belong to the fitted person the score maps to that gt person, with the matched share that
placing them would give; and a rule a stage could apply without the truth (a fitted person with no
track in a view at an instant, a quarter or more of whose silhouette that view sees while two other
views follow them, placed there):
how many of its placements land on their own gt person (IoU >= 0.25) and how many do not. The
potential of a design, not a stage of the kit.

    .venv/bin/python benchmarks/placement_potential.py /work/bench/ident/crowd6_seed0 [...]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

SPLAT_PX = 2  # vertex splat radius: the open body's vertices lie 1-3 px apart at these sizes
RULE_SHARE = 0.25  # the rule: a person is placed where the view sees this share of their silhouette
RULE_VIEWS = 2  # ... while this many other views follow them


def label_map(cam, bodies: list, t_ref: float, H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) index of the fitted body nearest the camera at each pixel (-1: none), and each body's
    pixel count alone (B,); ``bodies`` are (frame_times (T,), vertices (T, V, 3)) per person."""
    depth = np.full(H * W, np.inf)
    label = np.full(H * W, -1)
    alone = np.zeros(len(bodies), np.int64)
    offs = np.arange(-SPLAT_PX, SPLAT_PX + 1)
    for b, (times, verts) in enumerate(bodies):
        k = int(np.argmin(np.abs(times - t_ref)))
        if abs(times[k] - t_ref) > 0.05:
            continue
        z = cam.to_camera(verts[k])[:, 2]
        uv = cam.project(verts[k])
        ok = np.isfinite(uv).all(1) & (z > 0)
        uv = np.clip(uv[ok], -1e6, 1e6)  # far outside the image: no int overflow
        u0, v0, z = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int), z[ok]
        shape = (len(u0), len(offs), len(offs))
        u = np.broadcast_to(u0[:, None, None] + offs[None, :, None], shape).ravel()
        v = np.broadcast_to(v0[:, None, None] + offs[None, None, :], shape).ravel()
        zz = np.repeat(z, len(offs) ** 2)
        inb = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        idx, zz = v[inb] * W + u[inb], zz[inb]
        best = np.full(H * W, np.inf)
        np.minimum.at(best, idx, zz)  # this body's own depth per pixel
        alone[b] = int(np.isfinite(best).sum())
        nearer = best < depth
        depth[nearer], label[nearer] = best[nearer], b
    return label.reshape(H, W), alone


def potential(ws_path: Path) -> dict:
    from mamma_kit.body.lbs import pose_mesh_np
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.filled import load_identities, load_masks
    from mamma_kit.core.smplxfile import read_smplx_result
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.identities import camera_pairing, frame_scores

    ws = Workspace(ws_path)
    rig, _ = read_calibration(ws.calibration)
    clocks, _ = read_timing(ws.timing)
    scores = frame_scores(ws, load_identities(ws), clocks)
    model = load_body_model(ws.load_capture().body_model)
    pids, bodies = [], []
    for f in ws.person_files():
        r = read_smplx_result(f)
        pids.append(int(f.stem.split("_")[-1]))
        bodies.append((r.frame_times, pose_mesh_np(model, r.params())[0]))
    close = np.ones((5, 5), np.uint8)
    ident = load_identities(ws)
    to_gt = scores["person_to_gt"]
    cams = ws.load_capture().camera_names
    # per camera and person: the reference times at which one of its tracks there is present
    seen_at: dict[tuple[str, int], np.ndarray] = {}
    for c in cams:
        mt = load_masks(ws, c)
        t_ref = clocks[c].to_ref(mt.frame_times)
        p_tk = ident.person_frames(c, mt.track_ids, t_ref)
        for p in pids:
            seen_at[c, p] = t_ref[((p_tk == p) & mt.present).any(1)]
    missed = placed = right = rule_true = rule_false = 0
    for c in cams:
        pred = load_masks(ws, c)
        _, tg, _, seen_tp, on_tk = camera_pairing(ws, c, pred)
        gt = MaskTracks.load(ws.gt_dir / "masks" / f"{c}.npz")
        gcol = {int(g): j for j, g in enumerate(gt.track_ids)}
        pid_tk = ident.person_frames(c, pred.track_ids, clocks[c].to_ref(pred.frame_times))
        W, H = gt.image_size
        covered = np.zeros_like(seen_tp)
        t_i, k_i = np.nonzero(on_tk >= 0)
        covered[t_i, on_tk[t_i, k_i]] = True
        for t in range(len(gt.frame_times)):
            t_ref = float(clocks[c].to_ref(gt.frame_times[t:t + 1])[0])
            lab, alone = label_map(rig[c], bodies, t_ref, H, W)
            sil = [cv2.morphologyEx((lab == b).astype(np.uint8), cv2.MORPH_CLOSE, close).astype(bool)
                   for b in range(len(bodies))]
            for j in np.flatnonzero(seen_tp[t] & ~covered[t]):
                m = gt.mask(t, j)
                iou = [(s & m).sum() / max((s | m).sum(), 1) for s in sil]
                missed += 1
                if max(iou, default=0.0) >= 0.25:
                    placed += 1
                    right += to_gt.get(pids[int(np.argmax(iou))]) == int(gt.track_ids[j])
            # a rule a stage could apply without the truth: a fitted person with no track in this view
            # now, a quarter or more of whose silhouette the view sees, is placed there
            tracked = set(pid_tk[tg[t], pred.present[tg[t]]].tolist()) if tg[t] >= 0 else set()
            for b, s in enumerate(sil):
                if pids[b] in tracked or alone[b] == 0 or (lab == b).sum() < RULE_SHARE * alone[b]:
                    continue
                # ... and two other views follow the person then (the fit holds a body where no view
                # does, e.g. behind a wall: it is not placed)
                views = sum(bool(len(seen_at[o, pids[b]]) and np.abs(seen_at[o, pids[b]] - t_ref).min() < 0.05)
                            for o in cams if o != c)
                if views < RULE_VIEWS:
                    continue
                j = gcol.get(to_gt.get(pids[b], -1), -1)
                ok = j >= 0 and gt.present[t, j] and (s & gt.mask(t, j)).sum() / max((s | gt.mask(t, j)).sum(), 1) >= 0.25
                rule_true += bool(ok)
                rule_false += not ok
    n_seen = scores["person_view_frames"]
    return {"seen": n_seen, "matched": scores["matched"], "uncovered": missed, "placeable": placed,
            "placeable_right": int(right), "matched_if_placed": round(scores["matched"] + right / n_seen, 4),
            "rule_right": rule_true, "rule_wrong": rule_false}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("workspaces", type=Path, nargs="+")
    args = ap.parse_args()
    print(f"{'capture':40s} {'seen':>6s} {'matched':>8s} {'uncovered':>9s} {'placeable':>9s} {'right':>6s} "
          f"{'matched if placed':>17s}  rule: placed on their person / not")
    for ws in args.workspaces:
        r = potential(ws)
        print(f"{str(ws):40s} {r['seen']:6d} {100 * r['matched']:7.1f}% {r['uncovered']:9d} {r['placeable']:9d} "
              f"{r['placeable_right']:6d} {100 * r['matched_if_placed']:16.1f}%  {r['rule_right']} / {r['rule_wrong']}",
              flush=True)


if __name__ == "__main__":
    main()
