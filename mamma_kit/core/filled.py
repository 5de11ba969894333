"""What the stages after `mamma-kit fill` read: each view's tracks with the ones the fill added, and
the identities with them (fill/identities.json), when the fill was made from the match's current
identities.json; otherwise the match's own (a match run again after the fill makes the fill stale
until it runs again)."""

from __future__ import annotations

import hashlib
from pathlib import Path

from mamma_kit.core.identities import Identities, read_identities
from mamma_kit.core.tracks import KeypointTracks, LandmarkTracks, MaskTracks, append_tracks
from mamma_kit.core.workspace import Workspace

FILL_IDENTITIES = "identities.json"


def identities_digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def fill_is_current(ws: Workspace) -> bool:
    """Whether fill/identities.json was made from the identities.json there is now."""
    p = ws.fill_dir / FILL_IDENTITIES
    if not (p.is_file() and ws.identities.is_file()):
        return False
    return read_identities(p).settings.get("fill", {}).get("from_identities") == identities_digest(ws.identities)


def load_identities(ws: Workspace) -> Identities:
    return read_identities(ws.fill_dir / FILL_IDENTITIES if fill_is_current(ws) else ws.identities)


def _with_fill(ws: Workspace, kind: str, cam: str, base_path: Path, cls):
    base = cls.load(base_path)
    extra = ws.fill_file(kind, cam)
    if extra.is_file() and fill_is_current(ws):
        return append_tracks(base, cls.load(extra))
    return base


def track_files(ws: Workspace, kind: str, cam: str) -> list:
    """The camera's keypoint or landmark files as core.trackrows.TrackFile, to be read a window at a
    time: its own, then the fill's (its tracks' columns follow the camera's own, as in load_*)."""
    from mamma_kit.core.trackrows import TrackFile

    cls, base = {"keypoints": (KeypointTracks, ws.keypoints_file(cam)),
                 "landmarks": (LandmarkTracks, ws.landmarks_file(cam))}[kind]
    files = [TrackFile(base, cls, f"{kind[:-1]} file")]
    extra = ws.fill_file(kind, cam)
    if extra.is_file() and fill_is_current(ws):
        files.append(TrackFile(extra, cls, f"{kind[:-1]} file"))
    return files


def load_masks(ws: Workspace, cam: str) -> MaskTracks:
    return _with_fill(ws, "masks", cam, ws.mask_file(cam), MaskTracks)


def load_keypoints(ws: Workspace, cam: str) -> KeypointTracks:
    return _with_fill(ws, "keypoints", cam, ws.keypoints_file(cam), KeypointTracks)


def load_landmarks(ws: Workspace, cam: str) -> LandmarkTracks:
    return _with_fill(ws, "landmarks", cam, ws.landmarks_file(cam), LandmarkTracks)


def fill_inputs(ws: Workspace, cams: list[str]) -> list[Path]:
    """The fill's files a later stage's manifest should hash (none when the fill is stale or absent)."""
    if not fill_is_current(ws):
        return []
    return [ws.fill_dir / FILL_IDENTITIES] + [p for c in cams for k in ("masks", "keypoints", "landmarks")
                                              if (p := ws.fill_file(k, c)).is_file()]
