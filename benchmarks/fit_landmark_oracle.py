"""How good must the hand landmarks be for the fit? Ground truth in place of the network, refit.

    python benchmarks/fit_landmark_oracle.py WORKSPACE [--out /work/tmp/oracle]

WORKSPACE is a fitted synthetic capture (e.g. `mamma-kit demo --out DIR`). For each variant a copy
of it (without smplx/, report/, .cache/) gets the network's landmarks of some parts replaced by the
renderer's (visibility and sigma stay the network's), with noise in % of the box height: ``iid``
per landmark and axis, or ``offset`` shared by all the landmarks of one instance (a hand seen
whole but misplaced, which is how the network's hand errors come). The fit (stages 1-3, default
settings) runs on each and the MPJPE is printed beside the network's own.

Issue 22 used it to find that the hands' landmarks alone decide half of the demo's error, and
that a shared offset hurts far more than the same size of independent noise.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from refit import fresh_copy, refit  # noqa: E402

VARIANTS = {  # name: (parts, iid %, offset %)
    "network": ((), 0.0, 0.0),
    "hands truth": (("left_hand", "right_hand"), 0.0, 0.0),
    "hands truth + 4 % iid": (("left_hand", "right_hand"), 4.0, 0.0),
    "hands truth + 3 % offset": (("left_hand", "right_hand"), 1.0, 3.0),
    "hands truth + 5 % offset": (("left_hand", "right_hand"), 1.0, 5.0),
}


def replace_landmarks(ws, parts: tuple[str, ...], iid: float, offset: float, seed: int = 0) -> None:
    """In place: the landmarks of ``parts`` in ws/landmarks/*.npz become the truth plus noise."""
    from mamma_kit.body import skeleton as sk
    from mamma_kit.body.model import load_body_model
    from mamma_kit.core.tracks import LandmarkTracks
    from mamma_kit.evaluation.landmarks import landmark_pairs
    from mamma_kit.landmarks.gt import gt_landmarks_file

    if not parts:
        return
    body = load_body_model("open")
    part_l = body.vertex_part[np.asarray(body.landmark_ids)]
    sel = np.isin(part_l, [sk.PART_NAMES.index(n) for n in parts])
    rng = np.random.default_rng(seed)
    for path in sorted(ws.landmarks_dir.glob("*.npz")):
        got = landmark_pairs(ws, path.stem)
        if got is None:
            continue
        d = got[0]
        pred, gt = LandmarkTracks.load(path), LandmarkTracks.load(gt_landmarks_file(ws, path.stem))
        (ti, ki), (tg, kg) = d["index_p"], d["index_g"]
        h = d["box_h"][:, None, None] / 100.0
        xy = gt.xy[tg, kg][:, sel] + rng.normal(size=(len(ti), int(sel.sum()), 2)) * iid * h \
            + rng.normal(size=(len(ti), 1, 2)) * offset * h
        rows = pred.xy[ti, ki]
        rows[:, sel] = xy
        pred.xy[ti, ki] = rows
        pred.save(path)


def main() -> None:
    from mamma_kit.core import log

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--out", type=Path, default=Path("/tmp/mk_fit_oracle"))
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    log.set_quiet(True)
    for i, (name, (parts, iid, offset)) in enumerate(VARIANTS.items()):
        ws = fresh_copy(a.workspace, a.out / f"v{i}")
        replace_landmarks(ws, parts, iid, offset)
        m = refit(ws, a.threads)
        print(f"{name:26s} MPJPE {m['mpjpe_mm']:5.1f} mm (body {m['mpjpe_body_mm']:.1f}, hands "
              f"{m['mpjpe_hands_mm']:.1f}), PA {m['pa_mpjpe_mm']:.1f}", flush=True)


if __name__ == "__main__":
    main()
