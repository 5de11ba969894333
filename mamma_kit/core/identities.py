"""identities.json: which per-view track shows which person (written by `mamma-kit match`).

::

    {
      "format": "mamma-kit-identities", "version": 1,
      "producer": {...},
      "cameras": ["cam0", "cam1", ...],
      "assignments": {"cam0": {"3": 0, "5": 1}, ...},   # per view: track id -> global person id
      "segments": {"cam0": [[7, 0.0, 12.4, 0], [7, 14.0, 30.1, 1]]},   # tracks that change person
      "persons": [{"id": 0, "views": 4, "tracks": [{"camera": "cam0", "track": 3, "frames": 120}, ...]}],
      "unassigned": [{"camera": "cam2", "track": 9, "reason": "..."}],
      "pairs": {"cam0|cam1": {"rows": [track ids of cam0], "cols": [track ids of cam1],
                              "affinity": [[...]], "distance": [[...]], "distance_px": [[...]],
                              "shared_frames": [[...]], "shared_landmarks": [[...]]}},
      "rejected": [{"a": ["cam0", 3], "b": ["cam1", 4], "affinity": 0.1, "reason": "..."}],
      "settings": {...}, "diagnostics": {...}
    }

Person ids are 0..P-1, ordered by how much the views see the person (most first). Tracks that
are no person of the capture (seen by one camera only, a bystander beyond ``--people``, no usable
landmarks) are listed under ``unassigned`` with the reason and have no person id.

A per-view track can follow one person and then another (people who cross, a tracker that
jumps): ``segments`` then gives, per camera, [track, start, end, person] with start and end on
the reference clock in seconds (inclusive); the track's frames outside its segments show no
person. ``assignments`` still names each such track's person for most of its frames, for
readers that take a track as a whole. ``pieces(camera)`` gives both kinds in one list.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_json, write_json

FORMAT = "mamma-kit-identities"
VERSION = 2  # 2: segments


@dataclass
class Identities:
    cameras: list[str]
    assignments: dict[str, dict[int, int]]  # camera -> {track id: person id}
    pairs: dict = field(default_factory=dict)  # "camA|camB" -> affinity record
    rejected: list = field(default_factory=list)
    unassigned: list = field(default_factory=list)
    settings: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)
    producer: dict = field(default_factory=dict)
    track_frames: dict = field(default_factory=dict)  # (camera, track) -> frames with landmarks
    # camera -> [(track id, start s, end s, person id)] for tracks that change person (reference clock)
    segments: dict[str, list[tuple[int, float, float, int]]] = field(default_factory=dict)

    # ---- queries ------------------------------------------------------------------------
    def person_of(self, camera: str, track_id: int) -> int | None:
        return self.assignments.get(camera, {}).get(int(track_id))

    @property
    def person_ids(self) -> list[int]:
        return sorted({p for m in self.assignments.values() for p in m.values()})

    def tracks_of(self, person: int) -> list[tuple[str, int]]:
        """(camera, track id) of every track showing ``person``, cameras in rig order."""
        return [(c, t) for c in self.cameras for t, p in sorted(self.assignments.get(c, {}).items()) if p == person]

    def views_of(self, person: int) -> list[str]:
        return sorted({c for c, _ in self.tracks_of(person)}, key=self.cameras.index)

    def pieces(self, camera: str) -> list[tuple[int, int, float, float]]:
        """(track id, person id, start, end) of every assigned piece of the camera's tracks: a
        segmented track's segments, every other track whole (start -inf, end +inf)."""
        segs = self.segments.get(camera, [])
        split = {int(t) for t, *_ in segs}
        whole = [(int(t), int(p), -np.inf, np.inf) for t, p in sorted(self.assignments.get(camera, {}).items())
                 if int(t) not in split]
        return whole + [(int(t), int(p), float(a), float(b)) for t, a, b, p in segs]

    def person_frames(self, camera: str, track_ids: np.ndarray, times_ref: np.ndarray) -> np.ndarray:
        """(T, K) person id of each of the camera's tracks at each of its frames (reference
        times ``times_ref`` (T,)); -1 where the track shows no person of the capture."""
        col = {int(t): k for k, t in enumerate(track_ids)}
        t = np.asarray(times_ref, float)
        out = np.full((len(t), len(track_ids)), -1, np.int64)
        for tid, p, a, b in self.pieces(camera):
            k = col.get(tid)
            if k is not None:
                out[(t >= a - 1e-9) & (t <= b + 1e-9), k] = p
        return out

    def persons(self) -> list[dict]:
        out = []
        for p in self.person_ids:
            tracks = self.tracks_of(p)
            out.append({"id": p, "views": len({c for c, _ in tracks}),
                        "tracks": [{"camera": c, "track": t, "frames": int(self.track_frames.get((c, t), 0))}
                                   for c, t in tracks]})
        return out

    # ---- I/O ----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "format": FORMAT, "version": VERSION, "producer": self.producer, "cameras": list(self.cameras),
            "assignments": {c: {str(t): int(p) for t, p in sorted(m.items())} for c, m in self.assignments.items()},
            "segments": {c: [[int(t), round(float(a), 6), round(float(b), 6), int(p)] for t, a, b, p in v]
                         for c, v in self.segments.items() if v},
            "persons": self.persons(), "unassigned": self.unassigned, "pairs": self.pairs,
            "rejected": self.rejected, "settings": self.settings, "diagnostics": self.diagnostics,
        }

    @classmethod
    def from_dict(cls, d: dict, path: Path | str = "identities.json") -> "Identities":
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise UserError(f"{Path(path).name} is not a mamma-kit identities file",
                            "run `mamma-kit match WORKSPACE` to write it")
        if int(d.get("version", 0)) > VERSION:
            raise UserError(f"{Path(path).name} has format version {d.get('version')}, this mamma-kit reads {VERSION}",
                            "update mamma-kit or run `mamma-kit match` again")
        try:
            assignments = {str(c): {int(t): int(p) for t, p in m.items()} for c, m in d["assignments"].items()}
            frames = {(tr["camera"], int(tr["track"])): int(tr.get("frames", 0))
                      for per in d.get("persons", []) for tr in per.get("tracks", [])}
            segments = {str(c): [(int(t), float(a), float(b), int(p)) for t, a, b, p in v]
                        for c, v in d.get("segments", {}).items()}
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise UserError(f"{Path(path).name} is malformed ({e})", "run `mamma-kit match` again") from None
        return cls(list(d.get("cameras", list(assignments))), assignments, d.get("pairs", {}), d.get("rejected", []),
                   d.get("unassigned", []), d.get("settings", {}), d.get("diagnostics", {}), d.get("producer", {}),
                   frames, segments)


def write_identities(path: str | Path, ident: Identities) -> Path:
    return write_json(path, ident.to_dict())


def read_identities(path: str | Path) -> Identities:
    p = Path(path)
    if not p.is_file():
        raise UserError(f"no identities file at {p}", "run `mamma-kit match WORKSPACE` first")
    return Identities.from_dict(read_json(p, "identities.json"), p)
