"""Cross-view identities against ground truth: the fraction of tracks given the right person.

Each per-view track is first tied to the ground-truth person it shows: by mask overlap with
gt/masks (the person it overlaps best in most of its frames) when masks/<cam>.npz exists, else
the track id is the gt person id (landmarks made from ground truth without masks). Global person
ids of identities.json are then mapped one-to-one to gt persons by majority (a Hungarian
assignment maximising the number of agreeing tracks), so a person split into two groups or two
people merged into one both count as errors. A track without a person id counts as wrong.
``frame_accuracy`` weighs each track by its frames with landmarks (a 3-frame fragment counts less
than a whole-clip track).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from mamma_kit.core.filled import load_masks
from mamma_kit.core.identities import Identities, read_identities
from mamma_kit.core.tracks import LandmarkTracks, MaskTracks
from mamma_kit.core.workspace import Workspace


def track_gt_persons(ws: Workspace, cameras: list[str]) -> dict[tuple[str, int], int]:
    """(camera, track id) -> gt person id (-1 when it shows nobody)."""
    from mamma_kit.evaluation.masks import compare_camera

    out: dict[tuple[str, int], int] = {}
    for c in cameras:
        gp = ws.gt_dir / "masks" / f"{c}.npz"
        if ws.mask_file(c).is_file() and gp.is_file():
            e = compare_camera(MaskTracks.load(ws.mask_file(c)), MaskTracks.load(gp))
            ids = MaskTracks.load(ws.mask_file(c)).track_ids
            for k, tid in enumerate(ids):
                seq = e.track_gt_frames[:, k]
                seq = seq[seq >= 0]
                out[(c, int(tid))] = int(np.bincount(seq).argmax()) if len(seq) else e.track_to_gt.get(int(tid), -1)
        elif ws.landmarks_file(c).is_file():
            for tid in LandmarkTracks.load(ws.landmarks_file(c)).track_ids:
                out[(c, int(tid))] = int(tid)
    return out


def score(ident: Identities, truth: dict[tuple[str, int], int]) -> dict:
    tracks = [(c, t) for (c, t), g in truth.items() if g >= 0 and c in ident.cameras]
    pids = ident.person_ids
    gts = sorted({truth[k] for k in tracks})
    if not tracks:
        return {"accuracy": None, "tracks": 0}
    M = np.zeros((len(pids), len(gts)), np.int64)
    for c, t in tracks:
        p = ident.person_of(c, t)
        if p is not None:
            M[pids.index(p), gts.index(truth[(c, t)])] += 1
    r, cidx = linear_sum_assignment(-M) if M.size else ([], [])
    mapping = {pids[i]: gts[j] for i, j in zip(r, cidx) if M[i, j] > 0}
    correct = [k for k in tracks if mapping.get(ident.person_of(*k)) == truth[k]]
    wrong = [{"camera": c, "track": t, "gt_person": truth[(c, t)], "person": ident.person_of(c, t),
              "person_maps_to": mapping.get(ident.person_of(c, t))} for c, t in tracks if (c, t) not in correct]
    w = {k: max(int(ident.track_frames.get(k, 0)), 0) for k in tracks}
    total_w = sum(w.values())
    frame_acc = round(sum(w[k] for k in correct) / total_w, 4) if total_w else None
    split = sum(1 for g in gts if sum(1 for p in pids if M[pids.index(p), gts.index(g)] > 0) > 1)
    merged = sum(1 for p in pids if np.count_nonzero(M[pids.index(p)]) > 1)
    return {"accuracy": round(len(correct) / len(tracks), 4), "frame_accuracy": frame_acc,
            "tracks": len(tracks), "correct": len(correct),
            "persons": len(pids), "gt_persons": len(gts), "persons_split": split, "persons_merged": merged,
            "person_to_gt": {str(k): v for k, v in mapping.items()}, "wrong": wrong[:50]}


def evaluate(ws: Workspace) -> dict | None:
    if not ws.identities.is_file():
        return None
    ident = read_identities(ws.identities)
    return score(ident, track_gt_persons(ws, ident.cameras))


def camera_pairing(ws: Workspace, cam: str, pred: MaskTracks, min_visible: float = 0.25, min_iou: float = 0.25):
    """One camera's tracks ``pred`` against its gt persons, per gt frame: returns the mask comparison
    (evaluation.masks.compare_camera), each gt frame's pred frame (-1: none), ``present_tk`` (T_gt, K)
    the tracks present at each gt frame, ``seen_tp`` (T_gt, P)
    the gt persons the camera sees (at least ``min_visible`` of their surface landmarks visible) and
    ``on_tk`` (T_gt, K) the gt column each track is on, one-to-one per frame by mask IoU (Hungarian,
    IoU >= ``min_iou``; -1: none)."""
    from mamma_kit.evaluation.masks import compare_camera, pair_frames

    gt = MaskTracks.load(ws.gt_dir / "masks" / f"{cam}.npz")
    e = compare_camera(pred, gt)
    lt = LandmarkTracks.load(ws.gt_dir / "landmarks" / f"{cam}.npz")
    tg = pair_frames(gt.frame_times, pred.frame_times)  # gt frame -> pred frame
    present_tk = np.where(tg[:, None] >= 0, pred.present[np.clip(tg, 0, None)], False)
    lt_gt = pair_frames(gt.frame_times, lt.frame_times)
    T, P = len(gt.frame_times), len(gt.track_ids)
    seen_tp = np.zeros((T, P), bool)
    for j, g in enumerate(gt.track_ids):
        col = list(lt.track_ids).index(g)
        vis = np.where(lt_gt[:, None] >= 0, lt.visibility[np.clip(lt_gt, 0, None), col], 0.0)
        seen_tp[:, j] = (vis > 0.5).mean(1) >= min_visible
    on_tk = np.full(present_tk.shape, -1, np.int64)
    for t in range(T):
        iou = np.where(present_tk[t][:, None], e.iou_tkp[t], 0.0)
        if iou.size and iou.max() >= min_iou:
            r, cc = linear_sum_assignment(-iou)
            ok = iou[r, cc] >= min_iou
            on_tk[t, r[ok]] = cc[ok]
    return e, tg, present_tk, seen_tp, on_tk


def frame_scores(ws: Workspace, ident: Identities, clocks: dict, min_visible: float = 0.25,
                 min_iou: float = 0.25, fill: bool = True, placed: bool = False) -> dict:
    """Identities per frame against ground truth, as a user sees them. Per camera and frame, tracks
    and the gt persons the camera sees (at least ``min_visible`` of their surface landmarks visible)
    are paired one-to-one by mask IoU (Hungarian, IoU >= ``min_iou``: a track is on at most one
    person and a person has at most one track, as in CLEAR-MOT), and each pair carries the person
    id identities.json gives that track at that instant (its segments). Person ids are mapped
    one-to-one to gt persons by a Hungarian assignment over those person-view-frames. Returns:

    - ``matched``: share of seen person-view-frames whose track has their own person;
    - ``tracked``: share that some track is on, whatever its person (what the tracker found);
    - ``wrong``: whose track has another person (or a person that is nobody);
    - ``switches``: per camera and gt person, changes of the person id along the frames it has one;
      ``switch_events``: each one's camera, gt person, frame, person ids and the tracks before and after;
    - ``false_tracks``: tracks given a person that are on no gt person in most of those frames (an
      object, or a second track on someone's body);
    - ``tracks_on_nothing``: the tracker's tracks on no gt person in most of their frames;
    - ``person_to_gt``: the one-to-one map of person ids to gt persons the scores use;
    - ``missed_persons`` / ``extra_persons``: gt persons without a person id, person ids without a
      gt person. ``clocks``: camera -> ClockModel (camera time -> reference time) that match used.
    ``fill``: each view's tracks with those `mamma-kit fill` added (core.filled; pass the identities
    that name them), or the tracker's alone; ``placed``: and those `mamma-kit place` added.
    """
    per_cam = {}
    for c in ident.cameras:
        if not (ws.mask_file(c).is_file() and (ws.gt_dir / "masks" / f"{c}.npz").is_file()):
            continue
        pred = load_masks(ws, c, placed) if fill else MaskTracks.load(ws.mask_file(c))
        e, tg, present_tk, seen_tp, on_tk = camera_pairing(ws, c, pred, min_visible, min_iou)
        pid_tk = ident.person_frames(c, pred.track_ids, clocks[c].to_ref(pred.frame_times))
        pid_tk = np.where(tg[:, None] >= 0, pid_tk[np.clip(tg, 0, None)], -1)  # (T_gt, K)
        per_cam[c] = (e, pid_tk, present_tk, seen_tp, on_tk, pred.track_ids)
    gts = sorted({int(g) for e, *_ in per_cam.values() for g in e.gt_ids})
    pids = ident.person_ids
    cover, M, n_tracked = {}, np.zeros((len(pids), len(gts)), np.int64), 0
    for c, (e, pid_tk, present_tk, seen_tp, on_tk, _) in per_cam.items():
        cov = np.full(seen_tp.shape, -1, np.int64)  # person id on each gt person per frame
        t_idx, k_idx = np.nonzero(on_tk >= 0)
        cov[t_idx, on_tk[t_idx, k_idx]] = pid_tk[t_idx, k_idx]
        has = np.zeros(seen_tp.shape, bool)
        has[t_idx, on_tk[t_idx, k_idx]] = True
        n_tracked += int((has & seen_tp).sum())
        row = {p: i for i, p in enumerate(pids)}
        t_s, j_s = np.nonzero(seen_tp & (cov >= 0))
        np.add.at(M, (np.array([row[int(p)] for p in cov[t_s, j_s]], np.int64),
                      np.array([gts.index(int(e.gt_ids[j])) for j in j_s], np.int64)), 1)
        cover[c] = cov
    r, ci = linear_sum_assignment(-M) if M.size else ([], [])
    to_gt = {pids[i]: gts[j] for i, j in zip(r, ci) if M[i, j] > 0}
    n_seen = n_ok = n_wrong = switches = 0
    per_person = {g: [0, 0] for g in gts}
    false_tracks, on_nothing, switch_events = [], [], []
    for c, (e, pid_tk, present_tk, seen_tp, on_tk, tids) in per_cam.items():
        cov = cover[c]
        for j, g in enumerate(e.gt_ids):
            s = seen_tp[:, j]
            mapped = np.array([to_gt.get(int(p), -2) if p >= 0 else -1 for p in cov[s, j]], np.int64)
            ok = int(np.count_nonzero(mapped == g))
            n_seen += int(s.sum())
            n_ok += ok
            n_wrong += int(np.count_nonzero((mapped != g) & (cov[s, j] >= 0)))
            per_person[int(g)][0] += ok
            per_person[int(g)][1] += int(s.sum())
            at = np.nonzero(cov[:, j] >= 0)[0]
            seq = cov[at, j]
            sw = np.nonzero(seq[1:] != seq[:-1])[0]
            switches += len(sw)
            for i in sw:  # which track carried the person before and after: a changed track is the
                # tracker's (or the fill's) doing, the same track the match's
                t0, t1 = at[i], at[i + 1]
                k0, k1 = (int(np.nonzero(on_tk[t] == j)[0][0]) for t in (t0, t1))
                switch_events.append({"camera": c, "gt": int(g), "frame": int(t1), "from": int(seq[i]),
                                      "to": int(seq[i + 1]), "tracks": [int(tids[k0]), int(tids[k1])]})
        for k in range(on_tk.shape[1]):
            # given: the frames the track has a person in (a whole-track assignment names every frame)
            pres = present_tk[:, k]
            given = pres & (pid_tk[:, k] >= 0)
            if pres.sum() and (on_tk[pres, k] < 0).mean() > 0.5:
                on_nothing.append(f"{c}:{int(tids[k])}")
            if given.sum() and (on_tk[given, k] < 0).mean() > 0.5:
                false_tracks.append(f"{c}:{int(tids[k])}")
    return {"matched": round(n_ok / n_seen, 4) if n_seen else None,
            "tracked": round(n_tracked / n_seen, 4) if n_seen else None,
            "wrong": round(n_wrong / n_seen, 4) if n_seen else None,
            "person_view_frames": n_seen, "switches": switches, "switch_events": switch_events,
            "false_tracks": false_tracks, "tracks_on_nothing": on_nothing,
            "person_to_gt": {int(p): int(g) for p, g in to_gt.items()},
            "missed_persons": [g for g in gts if g not in to_gt.values()],
            "extra_persons": [p for p in pids if p not in to_gt],
            "persons": len(pids), "gt_persons": len(gts),
            "matched_per_person": {str(g): round(a / b, 4) if b else None for g, (a, b) in per_person.items()}}
