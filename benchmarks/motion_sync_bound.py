"""How precisely can the people's motion sync these cameras? The information in the keypoints.

For each camera pair of a workspace with keypoints, a calibration and the true clocks (a synthetic
capture's gt/, or timing.toml of a rig that shares one clock), the tracks are paired at the true
offset and the signed epipolar distance of every paired limb keypoint (in box heights) is
measured with its derivative with respect to the offset. From them:

- sigma: the robust spread of the distances at the truth (keypoint noise + calibration error);
- motion: the rms rate at which an offset error moves the distances (box heights per second);
- bound (white): sigma / sqrt(sum of squared rates), the Gauss-Newton standard deviation of the
  offset if the keypoints' errors were independent from frame to frame;
- bound (AR1): the same with the errors' measured lag-1 autocorrelation rho, inflated by
  sqrt((1 + rho) / (1 - rho)) (a first-order model of errors that persist over frames; the real
  correlation decays slower, so this is still optimistic);
- per camera: the AR1 bounds of all pairs combined (the offsets are solved jointly, the
  reference camera fixed).

It also prints where each pair's residual as motion sync scores it (mean capped absolute
distance, ``mamma_kit.timing.motion.residual``) is lowest on a 0.5 ms grid within +-60 ms of the
truth: the error of the method, against the bound.

Two checks of the bound's own assumption (that the errors average out), independent of how the
method searches:

- split halves: each pair's offset by robust Gauss-Newton on the signed distances (started at
  the truth, derivative from the frames on both sides), on the first and on the second half of
  the frames; if the errors averaged out, the halves would agree to about 1.4 bounds;
- joint whole-frame search: every combination of whole-frame errors up to +-JOINT_FRAMES for
  the cameras but the first, scored by the rig-wide residual (all pairs' observations at once);
  the truth's rank among them and the best combination. A truth that is not the best means the
  keypoints themselves place the minimum elsewhere, and no estimator on them can find the truth.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/motion_sync_bound.py WORKSPACE [WORKSPACE ...]
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np

from mamma_kit.core.calibfile import read_calibration
from mamma_kit.core.timingfile import read_timing
from mamma_kit.core.tracks import KeypointTracks
from mamma_kit.timing import motion as M

DT = 1e-3  # s: step of the numerical derivative with respect to the offset
JOINT_FRAMES = 3  # the joint search's range per camera, in whole frames
GRID_MS = np.arange(-60.0, 60.01, 0.5)


def pair_bound(a: M.View, b: M.View, offset: float) -> dict | None:
    F = a.cam.fundamental_to(b.cam)
    pairs = M.pair_tracks(a, b, F, offset)
    if not pairs:
        return None
    s0 = M.signed_series(a, b, F, pairs, offset)
    rate = (M.signed_series(a, b, F, pairs, offset + DT) - s0) / DT  # d distance / d offset
    ok = np.isfinite(s0) & np.isfinite(rate)
    med = np.median(s0[ok])
    sigma = 1.4826 * np.median(np.abs(s0[ok] - med))
    inlier = ok & (np.abs(s0 - med) < 3 * sigma)
    white = sigma / np.sqrt(np.sum(rate[inlier] ** 2))
    x0, x1 = s0[:-1], s0[1:]
    both = inlier[:-1] & inlier[1:]
    rho = float(np.clip(np.corrcoef(x0[both], x1[both])[0, 1], 0.0, 0.99)) if both.sum() > 10 else 0.0
    ar1 = white * np.sqrt((1 + rho) / (1 - rho))
    scores = [M.residual(a, b, F, pairs, offset + g * 1e-3)[0] for g in GRID_MS]
    return {"track_pairs": len(pairs), "observations": int(inlier.sum()), "sigma_pct": 100 * sigma,
            "motion_pct_per_s": 100 * float(np.sqrt(np.mean(rate[inlier] ** 2))), "rho": rho,
            "bound_white_ms": 1e3 * white, "bound_ar1_ms": 1e3 * ar1,
            "method_error_ms": float(GRID_MS[int(np.argmin(scores))])}


def gn_offset(a: M.View, b: M.View, F_33, pairs, offset: float, frames: np.ndarray) -> float:
    """Offset of b by robust Gauss-Newton on the signed distances of a's ``frames``, from ``offset``
    (motion sync's own normal equations, one pair)."""
    o = offset
    for _ in range(15):
        h, q, n = M.normal_equations(a, b, F_33, pairs, o, frames)
        if n == 0:
            return np.nan
        step = float(np.clip(-q / h, -0.5 * b.period, 0.5 * b.period))
        o += step
        if abs(step) < 1e-5 * b.period:
            break
    return o


def split_halves(a: M.View, b: M.View, offset: float) -> tuple[float, float] | None:
    """(first half, second half) Gauss-Newton offset errors (ms) of one pair, started at the truth."""
    F = a.cam.fundamental_to(b.cam)
    pairs = M.pair_tracks(a, b, F, offset)
    if not pairs:
        return None
    n = len(a.times)
    return tuple(1e3 * (gn_offset(a, b, F, pairs, offset, idx) - offset) for idx in (np.arange(n // 2), np.arange(n // 2, n)))


def joint_search(views: dict[str, M.View], true_offsets: dict[str, float]) -> dict:
    """Rank of the truth among all whole-frame error combinations by the rig-wide residual."""
    import itertools

    names = list(views)
    period = views[names[0]].period
    terms = []
    for k, an in enumerate(names):
        for bn in names[k + 1:]:
            a, b = views[an], views[bn]
            F = a.cam.fundamental_to(b.cam)
            pairs = M.pair_tracks(a, b, F, true_offsets[bn] - true_offsets[an])
            if pairs:
                terms.append((k, names.index(bn), a, b, F, pairs))
    scores = []
    for ks in itertools.product(range(-JOINT_FRAMES, JOINT_FRAMES + 1), repeat=len(names) - 1):
        err = np.r_[0.0, np.array(ks, float)] * period
        off = np.array([true_offsets[n] for n in names]) + err
        tot = n_obs = 0
        for i, j, a, b, F, pairs in terms:
            r, m = M.residual(a, b, F, pairs, off[j] - off[i])
            tot, n_obs = tot + r * m, n_obs + m
        scores.append((tot / max(n_obs, 1), ks))
    scores.sort()
    truth = next(k for k, (_, ks) in enumerate(scores) if not any(ks))
    return {"truth_rank": truth + 1, "combinations": len(scores), "best_frames": list(scores[0][1]),
            "truth_excess_pct": 100 * (scores[truth][0] / scores[0][0] - 1)}


def camera_bounds(names: list[str], pairs: dict[tuple[str, str], dict]) -> dict[str, float]:
    """Per-camera offset bound (ms) when all pairs' offsets are solved jointly, names[0] fixed."""
    idx = {n: k for k, n in enumerate(names)}
    L = np.zeros((len(names), len(names)))
    for (a, b), p in pairs.items():
        w = 1.0 / p["bound_ar1_ms"] ** 2
        i, j = idx[a], idx[b]
        L[i, i] += w
        L[j, j] += w
        L[i, j] -= w
        L[j, i] -= w
    sub = L[1:, 1:]
    if np.linalg.matrix_rank(sub) < len(names) - 1:
        return {}
    cov = np.linalg.inv(sub)
    return {n: float(np.sqrt(cov[k, k])) for k, n in enumerate(names[1:])}


def run(ws: Path) -> dict:
    truth = ws / "gt" if (ws / "gt" / "timing.toml").exists() else ws
    rig, _ = read_calibration(truth / "calibration.toml")
    clocks, _ = read_timing(truth / "timing.toml")
    views = {c.name: M.View.of(c, KeypointTracks.load(ws / "keypoints" / f"{c.name}.npz")) for c in rig}
    names = list(views)
    pairs = {}
    for k, an in enumerate(names):
        for bn in names[k + 1:]:
            a, b = views[an], views[bn]
            offset = float(np.median(a.times - clocks[bn].to_cam(clocks[an].to_ref(a.times))))
            p = pair_bound(a, b, offset)
            if p is not None:
                halves = split_halves(a, b, offset)
                pairs[(an, bn)] = {**p, "halves_ms": halves}
    ref = views[names[0]]
    t_mid = float(np.median(ref.times))
    true_offsets = {n: t_mid - clocks[n].to_cam(clocks[names[0]].to_ref(t_mid)) for n in names}
    return {"workspace": str(ws), "pairs": pairs, "cameras": camera_bounds(names, pairs),
            "joint": joint_search(views, true_offsets)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("workspaces", nargs="+", type=Path)
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args()
    out = []
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        for ws in args.workspaces:
            r = run(ws)
            out.append(r)
            print(f"\n{ws}")
            print(f"{'pair':<14}{'obs':>6}{'sigma %h':>10}{'motion %h/s':>13}{'rho':>6}{'bound white':>13}"
                  f"{'bound AR1':>11}{'method err':>12}{'halves (GN)':>18}")
            for (an, bn), p in r["pairs"].items():
                h = p["halves_ms"]
                print(f"{an + '-' + bn:<14}{p['observations']:>6}{p['sigma_pct']:>10.2f}{p['motion_pct_per_s']:>13.1f}"
                      f"{p['rho']:>6.2f}{p['bound_white_ms']:>10.2f} ms{p['bound_ar1_ms']:>8.2f} ms"
                      f"{p['method_error_ms']:>+9.1f} ms{h[0]:>+8.1f} /{h[1]:>+6.1f} ms")
            j = r["joint"]
            print(f"joint whole-frame search (+-{JOINT_FRAMES} frames): truth ranks {j['truth_rank']} of "
                  f"{j['combinations']} (rig-wide residual {j['truth_excess_pct']:.2f} % above the best, "
                  f"whose errors are {j['best_frames']} frames)")
            cams = ", ".join(f"{n} {v:.2f} ms" for n, v in r["cameras"].items())
            print(f"per camera (AR1, pairs solved jointly): {cams or 'the pairs do not connect the cameras'}")
    if args.json:
        args.json.write_text(json.dumps([{**r, "pairs": {f"{a}-{b}": p for (a, b), p in r["pairs"].items()}}
                                         for r in out], indent=1))


if __name__ == "__main__":
    main()
