"""What the stages after `mamma-kit fill` read: each view's tracks with the ones the fill added, and
the identities with them (fill/identities.json), when the fill was made from the match's current
identities.json; otherwise the match's own (a match run again after the fill makes the fill stale
until it runs again). With ``placed``, also the tracks `mamma-kit place` added from the fitted
bodies (place/identities.json, place/masks), when they were made from those identities and the
fit there is now: masks only, for what shows each view's people (the report, the identity score);
the fit reads the tracks that have keypoints and landmarks."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

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


def identities_source(ws: Workspace) -> Path:
    """The identities file the stages after the fill read: the fill's when current, else the match's."""
    return ws.fill_dir / FILL_IDENTITIES if fill_is_current(ws) else ws.identities


_FIT_DIGESTS: dict[tuple, str] = {}


def fit_digest(ws: Workspace) -> str:
    """One digest of the fit's results (smplx/person_*.npz); kept per the files' names, sizes and
    times, as every camera's tracks ask for it in turn."""
    files = ws.person_files()
    key = tuple((str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in files)
    if key not in _FIT_DIGESTS:
        h = hashlib.sha256()
        for p in files:
            h.update(p.name.encode())
            h.update(p.read_bytes())
        _FIT_DIGESTS[key] = h.hexdigest()
    return _FIT_DIGESTS[key]


def place_is_current(ws: Workspace) -> bool:
    """Whether place/identities.json was made from the identities the fit read and the fit there is now."""
    p = ws.place_dir / FILL_IDENTITIES
    if not (p.is_file() and ws.identities.is_file()):
        return False
    made = read_identities(p).settings.get("place", {})
    return made.get("from_identities") == identities_digest(identities_source(ws)) and \
        made.get("from_fit") == fit_digest(ws)


def load_identities(ws: Workspace, placed: bool = False) -> Identities:
    if placed and place_is_current(ws):
        return read_identities(ws.place_dir / FILL_IDENTITIES)
    return read_identities(identities_source(ws))


def _with_fill(ws: Workspace, kind: str, cam: str, base_path: Path, cls):
    base = cls.load(base_path)
    extra = ws.fill_file(kind, cam)
    if extra.is_file() and fill_is_current(ws):
        return append_tracks(base, cls.load(extra))
    return base


def open_tracks(ws: Workspace, kind: str, cam: str) -> "CameraTracks":
    """The camera's keypoint or landmark tracks, to be read a window of frames at a time: its own
    file, then the fill's when it is current (its tracks' columns follow the camera's own, as in
    load_keypoints / load_landmarks)."""
    from mamma_kit.core.trackrows import TrackFile

    cls, base = {"keypoints": (KeypointTracks, ws.keypoints_file(cam)),
                 "landmarks": (LandmarkTracks, ws.landmarks_file(cam))}[kind]
    files = [TrackFile(base, cls, f"{kind[:-1]} file")]
    extra = ws.fill_file(kind, cam)
    if extra.is_file() and fill_is_current(ws):
        files.append(TrackFile(extra, cls, f"{kind[:-1]} file"))
    return CameraTracks(files)


class CameraTracks:
    """A camera's track files (open_tracks: its own, then the fill's) read as one, a window of frames
    at a time: the tracks of every file side by side, in the files' order."""

    def __init__(self, files: list):
        self.files = files
        self.frame_times = files[0].frame_times
        self.track_ids = np.concatenate([f.track_ids for f in files])
        self.header = files[0].header
        self.image_size = self.header["image_size"]
        self.n = files[0].n
        self._offsets = np.cumsum([0] + [len(f.track_ids) for f in files])

    @property
    def n_frames(self) -> int:
        return len(self.frame_times)

    @property
    def producer(self) -> dict:
        return self.header.get("producer", {})

    def __getattr__(self, name: str):
        if name in ("source", "landmark_set", "model", "camera"):  # the header's strings
            return self.header.get(name, "")
        raise AttributeError(name)

    def rows(self, lo: int, hi: int, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Some fields of every row of frames lo:hi (the files' rows one after the other)."""
        parts = [f.rows(lo, hi, keys)[2] for f in self.files]
        return {k: np.concatenate([p[k] for p in parts]) for k in keys}

    def valid_tk(self) -> np.ndarray:
        return np.concatenate([f.valid_tk() for f in self.files], 1)

    def window(self, lo: int, hi: int, keys: tuple[str, ...]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The columns with rows in frames lo:hi (indices into track_ids) and their arrays there."""
        cols, parts = [], []
        for off, f in zip(self._offsets, self.files):
            c = f.columns_in(lo, hi)
            cols.append(off + c)
            parts.append(f.window(lo, hi, keys=keys, cols=c))
        return np.concatenate(cols), {k: np.concatenate([getattr(w, k) for w in parts], 1) for k in keys}

    def close(self) -> None:
        for f in self.files:
            f.close()

    def __enter__(self) -> "CameraTracks":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def load_masks(ws: Workspace, cam: str, placed: bool = False) -> MaskTracks:
    mt = _with_fill(ws, "masks", cam, ws.mask_file(cam), MaskTracks)
    extra = ws.place_dir / "masks" / f"{cam}.npz"
    if placed and extra.is_file() and place_is_current(ws):
        return append_tracks(mt, MaskTracks.load(extra))
    return mt


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
