"""The two-person lab recording (../shared/real/pose2sim-multiperson: four synchronised portrait
cameras, two people, bystanders in the background) told the wrong head count, or none.

    nice -n 10 python benchmarks/lab_people.py [--root /work/bench/lab-people] [--people 3,none,2]

For each head count: `init --calibration Calib.qca.txt --synced [--people N]`, then
`capture-to-smplx --to match` (pose tracks, keypoints, landmarks, the match over the take).
Printed per run: the tracks each view kept, the persons matched and the views each is seen in,
and what was set aside and why. The capture has two people: every run should end with exactly
two persons, each in all four views, and the bystanders set aside.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real" / "pose2sim-multiperson"
CAMS = ("cam01", "cam02", "cam03", "cam04")


def run(root: Path, people: int | None) -> dict:
    from mamma_kit.cli.app import main as cli
    from mamma_kit.core import log
    from mamma_kit.core.identities import read_identities
    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.pipeline import init_workspace

    ws_path = root / f"people-{people or 'none'}" / "ws"
    if not (ws_path / "capture.toml").is_file():
        log.set_quiet(True)
        init_workspace(ws_path, [REAL / "videos" / f"{c}.mp4" for c in CAMS],
                       calibration=REAL / "calibration" / "Calib.qca.txt", people=people, synced=True)
    t0 = time.perf_counter()
    try:
        cli(["capture-to-smplx", str(ws_path), "--to", "match", "-q"])
    except SystemExit as e:
        if e.code not in (0, None):
            raise
    ws = Workspace(ws_path)
    ident = read_identities(ws.identities)
    return {"people": people, "seconds": round(time.perf_counter() - t0, 1),
            "tracks": {c: len(MaskTracks.load(ws.mask_file(c)).track_ids) for c in CAMS},
            "persons": {p: ident.views_of(p) for p in ident.person_ids},
            "set_aside": [f"{', '.join(d['tracks'])}: {d['reason']}" for d in ident.diagnostics.get("set_aside", [])]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("/work/bench/lab-people"))
    ap.add_argument("--people", default="3,none", help="head counts to try, comma-separated (none: not given)")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    rows = [run(a.root, None if p == "none" else int(p)) for p in a.people.split(",")]
    print("| --people | tracks kept per view | persons matched | views per person | set aside |")
    print("|---|---|---:|---|---|")
    for r in rows:
        print(f"| {r['people'] or 'not given'} | {', '.join(f'{c} {n}' for c, n in r['tracks'].items())} | "
              f"{len(r['persons'])} | {'; '.join(f'{p}: {len(v)}' for p, v in r['persons'].items())} | "
              f"{'; '.join(r['set_aside']) or '-'} |")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
