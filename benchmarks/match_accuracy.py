"""Identity accuracy of `mamma-kit match` over camera counts, on rendered synthetic captures.

For each capture (crowd-6, iphone-outdoor-duo; rendered by `mamma-kit synth` if the folder does not
hold one yet) and each camera count (2/3/4/8, cameras spread evenly around the ring), landmarks
are the renderer's ground truth with noise of 1.2 % of the box height and 5 % outliers
(`mamma-kit landmarks --source gt`), over several noise seeds. Frames are paired by the true
clocks (gt/timing.toml) and the calibration is gt/calibration.toml.

Printed per case: identity accuracy (fraction of tracks given the right person), persons found,
time; and the same landmarks through a baseline in the style of the official code (per-pair mean
symmetric epipolar distance in pixels, affinity exp(-D/50), 0 above 80 px, Hungarian, keep
> 0.4, then union-find over the kept matches), on the same pair distances. With --builtin the
chain runs from the builtin masks instead (track -> landmarks re-mapped to those tracks ->
match), which adds the tracker's broken and switched tracks.

    nice -n 10 python benchmarks/match_accuracy.py --root /work/data/track_match --seeds 3 [--builtin]

With --chain the whole chain runs as a user runs it, on captures that stress identities: crowd-6
(six people, eight cameras) at three seeds and room-wander (a furnished room, four people, two of
them dressed alike, two who leave through a door and come back, 24 s). `mamma-kit track`
(the default pose backend), `keypoints`, `landmarks` (MammaNet) and `match` run on the videos
with the true calibration and clocks, and the identities are scored per frame against the
renderer's masks (mamma_kit.evaluation.identities.frame_scores): the share of person-view-frames
(a camera, a frame, a person it sees) given their own person, identity switches, tracks given a
person that show nobody (false tracks), the tracker's tracks on nobody (furniture), and missed or
extra persons.

    nice -n 10 python benchmarks/match_accuracy.py --root /work/bench/ident --chain

The chain goes on through `mamma-kit fit` and `mamma-kit place` (the fitted bodies placed in the
views that lost them); the scores are of every track then, with those before the placement and
before the fill beside them. ``--from match`` runs the match and the stages after it again on the
tracks, keypoints and landmarks an earlier run left in --root (what a change to the matching needs);
``--from place`` only the placement, on the fit there.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

CASES = [("crowd-6", "crowd6_s025_f60", 60, 0.25), ("iphone-outdoor-duo", "duo_s020_f60", 60, 0.2)]


def ensure_capture(root: Path, recipe: str, folder: str, frames: int, scale: float) -> Path:
    ws = root / folder
    if not (ws / "capture.toml").is_file():
        from mamma_kit.synth.capture import synthesize

        print(f"rendering {recipe} into {ws} (frames {frames}, scale {scale}); this takes a while")
        synthesize(recipe, ws, frames=frames, scale=scale, board=False)
    return ws


def spread(cams: list[str], n: int) -> list[str]:
    idx = np.unique(np.round(np.linspace(0, len(cams), n, endpoint=False)).astype(int))
    return [cams[i] for i in idx]


def union_find_baseline(views, sub) -> dict:
    """Official-style grouping on the same pair distances (px, uncapped): see module doc."""
    from scipy.optimize import linear_sum_assignment

    from mamma_kit.core.identities import Identities
    from mamma_kit.matching.pairs import pair_distances

    parent = {}

    def find(x):
        parent.setdefault(x, x)
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a in range(len(views)):
        for b in range(a + 1, len(views)):
            r = pair_distances(views[a], views[b], cap=np.inf)
            D = np.nan_to_num(r.distance_px, nan=np.inf)
            A = np.where((D <= 80) & (r.shared_landmarks >= 5), np.exp(-D / 50), 0.0)
            ri, ci = linear_sum_assignment(1 - A)
            for i, j in zip(ri, ci):
                if A[i, j] > 0.4:
                    x, y = (a, int(views[a].track_ids[i])), (b, int(views[b].track_ids[j]))
                    parent[find(x)] = find(y)
    assign: dict[str, dict[int, int]] = {v.name: {} for v in views}
    roots: dict = {}
    for vi, v in enumerate(views):
        for k, tid in enumerate(v.track_ids):
            if v.valid_tk[:, k].any():
                r = find((vi, int(tid)))
                assign[v.name][int(tid)] = roots.setdefault(r, len(roots))
    return Identities([v.name for v in views], assign)


def run_case(ws_path: Path, cams: list[str], seed: int, builtin: bool) -> dict:
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import LandmarkTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.identities import score, track_gt_persons
    from mamma_kit.matching.match import MatchSettings
    from mamma_kit.matching.pairs import ViewTracks
    from mamma_kit.matching.windows import WindowSettings, match_take

    ws = Workspace(ws_path)
    rig, _ = read_calibration(ws.gt_dir / "calibration.toml")
    clocks, _ = read_timing(ws.gt_dir / "timing.toml")
    lts = {c: LandmarkTracks.load(ws.landmarks_file(c)) for c in cams}
    views = [ViewTracks.from_landmarks(lts[c], rig[c], clocks[c].to_ref(lts[c].frame_times)) for c in cams]
    t0 = time.perf_counter()
    ident = match_take(views, None, MatchSettings(), WindowSettings())  # what `mamma-kit match` runs
    secs = time.perf_counter() - t0
    truth = track_gt_persons(ws, cams)
    ours = score(ident, truth)
    base = score(union_find_baseline(views, cams), truth)
    return {"accuracy": ours["accuracy"], "frame_accuracy": ours["frame_accuracy"], "persons": ours["persons"],
            "gt_persons": ours["gt_persons"],
            "tracks": ours["tracks"], "seconds": secs, "baseline_accuracy": base["accuracy"],
            "baseline_persons": base["persons"], "wrong": ours["wrong"][:3]}


# (recipe, folder, frames or None for the recipe's duration, render scale, seed or None)
STAGES = ("track", "keypoints", "landmarks", "match", "fill", "fit", "place")
CHAIN_CASES = [("crowd-6", "crowd6_seed0", 60, 0.5, 0), ("crowd-6", "crowd6_seed11", 60, 0.5, 11),
               ("crowd-6", "crowd6_seed23", 60, 0.5, 23), ("room-wander", "room_wander", None, 0.5, None),
               # the same room for half as long: peak memory must not grow with the take
               ("room-wander", "room_wander_12s", 120, 0.5, None)]


def run_measured(stage: str, ws_path: Path) -> tuple[float, float]:
    """`mamma-kit STAGE WS` in its own process: wall seconds and peak resident memory (MB)."""
    from stage_process import run_stage

    extra = ["--backend", "pose"] if stage == "track" else []  # what `mamma-kit init` sets for real captures
    return run_stage([stage, str(ws_path), "--quiet", "--force", *extra])


def chain_case(root: Path, recipe: str, folder: str, frames, scale: float, seed, first: str = "track") -> dict:
    """Render (once), then track -> keypoints -> landmarks -> match -> fill with the true calibration
    and clocks (from stage ``first`` on: the earlier ones as an earlier run left them), and score the
    identities per frame."""
    import shutil

    from mamma_kit.core.filled import load_identities
    from mamma_kit.core.identities import read_identities
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.identities import frame_scores

    ws_path = root / folder
    if not (ws_path / "capture.toml").is_file():
        import subprocess
        import sys

        # in its own process: Linux keeps a process's peak memory across fork and exec, so a render
        # in this one would show in every stage's figure below
        print(f"rendering {recipe} into {ws_path}; this takes a while", flush=True)
        subprocess.run([sys.executable, "-m", "mamma_kit", "synth", recipe, "--out", str(ws_path), "--scale",
                        str(scale), "--no-board", "--quiet"] + (["--frames", str(frames)] if frames else [])
                       + (["--seed", str(seed)] if seed is not None else []), check=True)
    ws = Workspace(ws_path)
    shutil.copyfile(ws.gt_dir / "calibration.toml", ws.calibration)
    shutil.copyfile(ws.gt_dir / "timing.toml", ws.timing)
    secs, peak_mb = {}, {}
    for stage in STAGES[STAGES.index(first):]:
        secs[stage], peak_mb[stage] = run_measured(stage, ws_path)
    clocks, _ = read_timing(ws.timing)
    r = frame_scores(ws, load_identities(ws, placed=True), clocks, placed=True)
    # before the placement (the tracker's and the fill's tracks), and the match's own identities on
    # the tracker's tracks (before the fill), for comparison
    keys = ("matched", "tracked", "wrong", "switches", "false_tracks")
    r["before_place"] = {k: v for k, v in frame_scores(ws, load_identities(ws), clocks).items() if k in keys}
    r["before_fill"] = {k: v for k, v in frame_scores(ws, read_identities(ws.identities), clocks, fill=False).items()
                        if k in keys}
    cams = ws.load_capture().camera_names
    r["tracks"] = sum(len(MaskTracks.load(ws.mask_file(c)).track_ids) for c in cams)
    r["seconds"] = secs
    r["peak_rss_mb"] = peak_mb
    r["cameras"] = len(cams)
    return r


def main_chain(args) -> None:
    rows = []
    print(f"{'capture':22s} {'cams':>4s} {'tracks':>6s} {'on nobody':>9s} {'persons':>7s} {'matched':>8s} "
          f"{'wrong':>6s} {'switches':>8s} {'false':>5s} {'missed':>6s}  seconds (track/keypoints/landmarks/match/fill/fit/place)")
    for recipe, folder, frames, scale, seed in CHAIN_CASES:
        if args.case and folder not in args.case:
            continue
        r = chain_case(args.root, recipe, folder, frames, scale, seed, args.first)
        name = f"{recipe} seed {seed}" if seed is not None else recipe
        rows.append({"capture": name, **r})
        s = {k: r["seconds"].get(k, "-") for k in STAGES}
        print(f"{name:22s} {r['cameras']:4d} {r['tracks']:6d} {len(r['tracks_on_nothing']):9d} "
              f"{r['persons']:3d}/{r['gt_persons']:<3d} {100 * r['matched']:7.1f}% {100 * r['wrong']:5.1f}% "
              f"{r['switches']:8d} {len(r['false_tracks']):5d} {len(r['missed_persons']):6d}  "
              + "/".join(str(s[k]) for k in STAGES), flush=True)
        for key, what in (("before_place", "before the placement (the tracker's and the fill's tracks)"),
                          ("before_fill", "before the fill (the tracker's tracks)")):
            b = r[key]
            print(f"    {what}: matched {100 * b['matched']:.1f}%, tracked {100 * b['tracked']:.1f}%, wrong "
                  f"{100 * b['wrong']:.1f}%, switches {b['switches']}, false {len(b['false_tracks'])}", flush=True)
        print("    peak memory MB (track/keypoints/landmarks/match/fill/fit/place): "
              + "/".join(f"{r['peak_rss_mb'][k]:.0f}" if k in r["peak_rss_mb"] else "-" for k in STAGES), flush=True)
        print(f"    matched per person {r['matched_per_person']}; false tracks {r['false_tracks']}; "
              f"tracks on nobody {r['tracks_on_nothing']}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=str))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("bench_data"), help="folder of the rendered captures")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--counts", default="2,3,4,8")
    ap.add_argument("--builtin", action="store_true", help="landmarks on builtin mask tracks instead of gt ids")
    ap.add_argument("--chain", action="store_true",
                    help="the whole chain from the videos (track, keypoints, landmarks, match), scored per frame")
    ap.add_argument("--from", dest="first", choices=STAGES, default="track",
                    help="with --chain: run from this stage on (the earlier stages' outputs in --root as they are)")
    ap.add_argument("--case", action="append", default=None, help="with --chain: only these folders; repeatable")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows here")
    args = ap.parse_args()
    from mamma_kit.cli.app import main as cli
    from mamma_kit.core import log

    log.set_quiet(True)

    def run(*a):
        try:
            cli([str(x) for x in a])
        except SystemExit as e:
            if e.code not in (0, None):
                raise RuntimeError(f"mamma-kit {' '.join(map(str, a))} failed ({e.code})")

    if args.chain:
        return main_chain(args)
    rows = []
    print(f"{'capture':20s} {'cams':>4s} {'seed':>4s} {'tracks':>6s} {'persons':>7s} {'accuracy':>8s} "
          f"{'by frames':>9s} {'union-find':>10s} {'match s':>7s}")
    for recipe, folder, frames, scale in CASES:
        ws = ensure_capture(args.root, recipe, folder, frames, scale)
        from mamma_kit.core.workspace import Workspace

        allcams = Workspace(ws).load_capture().camera_names
        if args.builtin:
            run("track", ws, "--backend", "builtin", "--quiet")
        elif (ws / "masks").is_dir():
            import shutil

            shutil.rmtree(ws / "masks")  # gt person ids as track ids
        for seed in range(args.seeds):
            run("landmarks", ws, "--source", "gt", "--noise", "1.2%", "--outliers", "0.05", "--seed", seed,
                "--force", "--quiet")
            for n in [int(x) for x in args.counts.split(",")]:
                if n > len(allcams):
                    continue
                cams = spread(allcams, n)
                r = run_case(ws, cams, seed, args.builtin)
                rows.append({"capture": recipe, "cameras": n, "seed": seed, **r})
                print(f"{recipe:20s} {n:4d} {seed:4d} {r['tracks']:6d} {r['persons']:3d}/{r['gt_persons']:<3d} "
                      f"{100 * r['accuracy']:7.1f}% {100 * r['frame_accuracy']:8.1f}% "
                      f"{100 * r['baseline_accuracy']:9.1f}% {r['seconds']:7.2f}")
    print("\nsummary (mean over seeds): identity accuracy, ours vs union-find baseline")
    for recipe, *_ in CASES:
        for n in [int(x) for x in args.counts.split(",")]:
            sel = [r for r in rows if r["capture"] == recipe and r["cameras"] == n]
            if sel:
                print(f"  {recipe:20s} {n} cameras: {100 * np.mean([r['accuracy'] for r in sel]):6.1f} %   "
                      f"baseline {100 * np.mean([r['baseline_accuracy'] for r in sel]):6.1f} %   "
                      f"({len(sel)} runs, {'builtin masks' if args.builtin else 'gt tracks'})")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    main()
