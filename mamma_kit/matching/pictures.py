"""A picture per camera of who is who: one frame with every track tinted in its person's colour
and labelled with the person id, and every track set aside (a bystander, an object, a duplicate)
outlined in grey with the reason, so a user sees what the match kept and what it rejected."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mamma_kit.core.identities import Identities
from mamma_kit.core.io import atomic_path
from mamma_kit.core.tracks import MaskTracks, track_colour

SHORT_REASONS = (("bystander", "bystander"), ("frames only", "seen briefly"), ("only", "one view only"),
                 ("duplicate", "duplicate"), ("not one of", "beyond --people"), ("no frame", "no landmarks"))


def short_reason(reason: str) -> str:
    for key, short in SHORT_REASONS:
        if key in reason:
            return short
    return reason[:24]


def picture_frame(mt: MaskTracks, person_tk: np.ndarray) -> int:
    """The frame showing the most tracks, set-aside ones counted too (the middle one among ties)."""
    n = mt.present.sum(1) + 0.5 * (mt.present & (person_tk < 0)).sum(1)
    if not len(n):
        return 0
    cand = np.flatnonzero(n == n.max())
    return int(cand[len(cand) // 2])


def draw_identities(rgb_hw3: np.ndarray, mt: MaskTracks, t: int, person_k: np.ndarray, reasons: dict[int, str],
                    camera: str, notes: dict[int, str] | None = None) -> np.ndarray:
    """Tracks present at frame t: tinted by person (person_k (K,) person id or -1) or outlined in grey
    with their reason (track id -> reason); ``notes``: track id -> a word after its person's label."""
    up = 2 if rgb_hw3.shape[0] < 500 else 1  # small videos drawn at twice their size, for legible labels
    img = cv2.resize(rgb_hw3, None, fx=up, fy=up, interpolation=cv2.INTER_LINEAR) if up > 1 else rgb_hw3.copy()
    H = img.shape[0]
    scale = max(0.45, H / 720)
    thick = max(1, int(round(2 * scale)))
    for k in np.flatnonzero(mt.present[t]):
        m = mt.mask(t, int(k))
        if up > 1:
            m = cv2.resize(m.astype(np.uint8), (img.shape[1], H), interpolation=cv2.INTER_NEAREST) > 0
        tid, p = int(mt.track_ids[k]), int(person_k[k])
        col = np.array(track_colour(p) if p >= 0 else (150, 150, 150), np.float32)
        if p >= 0:
            img[m] = (0.5 * img[m] + 0.5 * col).astype(np.uint8)
        cnts, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, cnts, -1, tuple(int(c) for c in col), thick)
        x1, y1 = mt.boxes[t, k, :2] * up
        text = f"P{p}" if p >= 0 else f"{tid}: {short_reason(reasons.get(tid, 'not matched'))}"
        text += f" {notes[tid]}" if notes and tid in notes else ""
        org = (int(max(0, x1)), int(max(12 * scale, y1 - 4 * scale)))
        cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.6 * scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
        cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.6 * scale, (255, 255, 255), thick, cv2.LINE_AA)
    kept = int((mt.present[t] & (person_k >= 0)).sum())
    label = f"{camera}  frame {t}  {kept} person track(s), {int(mt.present[t].sum()) - kept} set aside"
    cv2.putText(img, label, (int(6 * scale), H - int(8 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 0.5 * scale,
                (255, 255, 255), max(1, thick - 1), cv2.LINE_AA)
    return img


def write_identity_pictures(ws, ident: Identities, masks: dict[str, MaskTracks], times_ref: dict[str, np.ndarray],
                            folder: Path) -> list[Path]:
    """report/match/<cam>.png for every camera with mask tracks (masks: camera -> its tracks;
    times_ref: camera -> reference time of each of its mask frames)."""
    from mamma_kit.video.reader import VideoReader

    cap = ws.load_capture()
    out = []
    for c in ident.cameras:
        if c not in masks or c not in times_ref:
            continue
        mt = masks[c]
        person_tk = ident.person_frames(c, mt.track_ids, times_ref[c])
        t = picture_frame(mt, person_tk)
        reasons = {int(u["track"]): u["reason"] for u in ident.unassigned if u["camera"] == c}
        _, rgb = VideoReader(cap.cameras[c].video, cap.cameras[c].rotation).frame_index(t)
        img = draw_identities(rgb, mt, t, person_tk[t], reasons, c)
        path = folder / f"{c}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path, ".png") as tmp:
            if not cv2.imwrite(str(tmp), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
                raise OSError(f"could not write {path}")
        out.append(path)
    return out
