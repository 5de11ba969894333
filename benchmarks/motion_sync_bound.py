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
GRID_MS = np.arange(-60.0, 60.01, 0.5)


def signed_distance(F_33: np.ndarray, xa_n2: np.ndarray, xb_n2: np.ndarray) -> np.ndarray:
    """Signed distance (px) of b's points to the epipolar lines of a's points, F: a -> b."""
    ha = np.concatenate([xa_n2, np.ones_like(xa_n2[..., :1])], -1)
    hb = np.concatenate([xb_n2, np.ones_like(xb_n2[..., :1])], -1)
    lines = ha @ F_33.T
    return (hb * lines).sum(-1) / np.hypot(lines[..., 0], lines[..., 1])


def pair_series(a: M.View, b: M.View, F_33, pairs, offset: float) -> np.ndarray:
    """(T, S) signed distances in box heights, S = paired tracks x limb joints, NaN where unseen."""
    xb, hb = b.at(a.times - offset)
    cols = [signed_distance(F_33, a.xy[:, i], xb[:, j]) / np.sqrt(a.height[:, i, None] * hb[:, j, None])
            for i, j in pairs]
    return np.concatenate(cols, 1)


def pair_bound(a: M.View, b: M.View, offset: float) -> dict | None:
    F = a.cam.fundamental_to(b.cam)
    pairs = M.pair_tracks(a, b, F, offset)
    if not pairs:
        return None
    s0 = pair_series(a, b, F, pairs, offset)
    rate = (pair_series(a, b, F, pairs, offset + DT) - s0) / DT  # d distance / d offset
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
                pairs[(an, bn)] = p
    return {"workspace": str(ws), "pairs": pairs, "cameras": camera_bounds(names, pairs)}


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
                  f"{'bound AR1':>11}{'method err':>12}")
            for (an, bn), p in r["pairs"].items():
                print(f"{an + '-' + bn:<14}{p['observations']:>6}{p['sigma_pct']:>10.2f}{p['motion_pct_per_s']:>13.1f}"
                      f"{p['rho']:>6.2f}{p['bound_white_ms']:>10.2f} ms{p['bound_ar1_ms']:>8.2f} ms"
                      f"{p['method_error_ms']:>+9.1f} ms")
            cams = ", ".join(f"{n} {v:.2f} ms" for n, v in r["cameras"].items())
            print(f"per camera (AR1, pairs solved jointly): {cams or 'the pairs do not connect the cameras'}")
    if args.json:
        args.json.write_text(json.dumps([{**r, "pairs": {f"{a}-{b}": p for (a, b), p in r["pairs"].items()}}
                                         for r in out], indent=1))


if __name__ == "__main__":
    main()
