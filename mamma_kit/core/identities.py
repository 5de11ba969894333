"""identities.json: which per-view track shows which person (written by `mamma-kit match`).

::

    {
      "format": "mamma-kit-identities", "version": 1,
      "producer": {...},
      "cameras": ["cam0", "cam1", ...],
      "assignments": {"cam0": {"3": 0, "5": 1}, ...},   # per view: track id -> global person id
      "persons": [{"id": 0, "views": 4, "tracks": [{"camera": "cam0", "track": 3, "frames": 120}, ...]}],
      "unassigned": [{"camera": "cam2", "track": 9, "reason": "..."}],
      "pairs": {"cam0|cam1": {"rows": [track ids of cam0], "cols": [track ids of cam1],
                              "affinity": [[...]], "distance": [[...]], "distance_px": [[...]],
                              "shared_frames": [[...]], "shared_landmarks": [[...]]}},
      "rejected": [{"a": ["cam0", 3], "b": ["cam1", 4], "affinity": 0.1, "reason": "..."}],
      "settings": {...}, "diagnostics": {...}
    }

Person ids are 0..P-1, ordered by how many views see the person (most first). A track in no
group with another view still gets its own person id (a person seen by one camera); tracks with
no usable landmarks are listed under ``unassigned`` and have no person id.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_json, write_json

FORMAT = "mamma-kit-identities"
VERSION = 1


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
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise UserError(f"{Path(path).name} is malformed ({e})", "run `mamma-kit match` again") from None
        return cls(list(d.get("cameras", list(assignments))), assignments, d.get("pairs", {}), d.get("rejected", []),
                   d.get("unassigned", []), d.get("settings", {}), d.get("diagnostics", {}), d.get("producer", {}),
                   frames)


def write_identities(path: str | Path, ident: Identities) -> Path:
    return write_json(path, ident.to_dict())


def read_identities(path: str | Path) -> Identities:
    p = Path(path)
    if not p.is_file():
        raise UserError(f"no identities file at {p}", "run `mamma-kit match WORKSPACE` first")
    return Identities.from_dict(read_json(p, "identities.json"), p)
