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
