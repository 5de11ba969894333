"""Flash sync: camera clocks from a light switched on (or off, or a phone torch flashed) in view of
every camera.

Per camera:
1. a brightness signal from the decoded frames: each frame in grey, linearised (the video is gamma
   encoded; light adds in linear units), averaged into a small grid of cells (GRID_ROWS x
   GRID_COLS), so a whole take fits in memory; ``b_t`` is the grid's mean per frame;
2. steps: frame-to-frame jumps of ``b_t`` far above its own noise (MIN_SNR times the robust
   spread of the differences) and at least STEP_FRACTION of the largest; consecutive jumps of one
   sign are one step (a flash caught mid-exposure brightens two frames);
3. sub-frame time of each step from the frames around it: per cell, the level before and after;
   per frame and row band, the lit fraction ``f`` (least squares over the cells that the light
   changes and that never saturate). A row's exposure of length e is centred on
   t_k + (y - 1/2) R (frame time t_k, row position y in [0, 1], readout R of a rolling shutter), so
   the light came on at  t_f = t_k + (y - 1/2) R + e (1/2 - f). All partly lit (frame, row)
   observations give t_f, R and e by least squares, with weak priors on e and R (tight when the
   user gives them) for frames that do not determine them (a global shutter shows no row slope);
4. each camera's steps are matched to the reference camera's (same sign, the shift that pairs the
   most), and the clock is a line through the matched times (drift when the flashes span
   DRIFT_MIN_SPAN_S or more, else an offset).
Every frame's own timestamp is used (variable frame rate).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError

GRID_ROWS = 48
GRID_COLS = 16
# a step is a flash when its frame-to-frame jump is this many times the differences' robust spread
MIN_SNR = 8.0
# ... and at least this fraction of the take's largest jump (moving people and auto exposure make
# smaller steps)
STEP_FRACTION = 0.25
# ... and at least this fraction of the image's mean (linear) brightness: a compressed static scene
# can have almost no frame-to-frame noise, and a torch lights a good part of the view
MIN_RELATIVE_STEP = 0.02
# a cell whose grey level reaches this in any frame around the step is left out (clipped)
SATURATED = 250
# a partial fraction must be this many of its noise's standard deviations, and F_EDGE, from 0 and 1 (video
# encoders leave a few per cent of a frame's brightening in rows the light did not reach)
F_SIGMAS, F_EDGE = 4.0, 0.1
# a step timed from fewer partly lit rows than this takes its camera's exposure and readout from the
# camera's better-seen steps
POOL_MIN_OBSERVATIONS = 8
# drift is fitted when matched flashes span at least this long
DRIFT_MIN_SPAN_S = 20.0
DEFAULTS = {"exposure_s": 0.0, "readout_s": None, "gamma": 2.2, "min_snr": MIN_SNR}


@dataclass
class FlashSignal:
    """One camera's brightness grid: linear cell means per frame."""

    times: np.ndarray  # (T,) own clock, s
    lum_trc: np.ndarray  # (T, rows, cols) float32 linear luminance in [0, 1]
    sat_trc: np.ndarray  # (T, rows, cols) bool: a pixel of the cell is clipped

    @property
    def b_t(self) -> np.ndarray:
        return self.lum_trc.mean(axis=(1, 2))

    @property
    def period(self) -> float:
        return float(np.median(np.diff(self.times))) if len(self.times) > 1 else 1.0


@dataclass
class FlashEvent:
    t: float  # own clock: when the light changed (s)
    sign: int  # +1 on, -1 off
    snr: float  # the step against the frame-to-frame noise
    precision_s: float  # standard error of t
    frames: list[int]  # the transition's frame indices
    observations: int  # partly lit (frame, row band) observations used
    exposure_s: float
    readout_s: float
    info: dict = field(default_factory=dict)


def read_signal(path: Path, gamma: float = 2.2, rows: int = GRID_ROWS, cols: int = GRID_COLS) -> FlashSignal:
    """Decode every frame of a video into its brightness grid (vectorised per frame)."""
    import cv2

    from mamma_kit.video import VideoReader

    lut = ((np.arange(256) / 255.0) ** gamma).astype(np.float32)
    times, lum, sat = [], [], []
    for t, g in VideoReader(path).frames(fmt="gray"):
        if g.ndim == 3:
            g = g[..., 0]
        times.append(t)
        lum.append(cv2.resize(lut[g], (cols, rows), interpolation=cv2.INTER_AREA))
        sat.append(cv2.resize((g >= SATURATED).astype(np.float32), (cols, rows), interpolation=cv2.INTER_AREA) > 0)
    if len(times) < 8:
        raise UserError(f"{Path(path).name} has only {len(times)} frames: too short to find a flash in",
                        "record a few seconds before and after the flash")
    return FlashSignal(np.asarray(times, np.float64), np.stack(lum), np.stack(sat))


def load_signal(path: Path, cache: Path | None, digest: str | None, gamma: float) -> FlashSignal:
    """read_signal, reusing ``cache`` (an .npz) when it was made from the same video bytes and gamma:
    decoding is the slow part, and a failed sync must not throw away what it read."""
    from mamma_kit.core.io import read_npz, write_npz

    key = f"{digest}:{gamma}:{GRID_ROWS}x{GRID_COLS}"
    if cache is not None and digest and cache.is_file():
        z = read_npz(cache, "flash signal cache")
        if str(z.get("key", "")) == key:
            return FlashSignal(z["times"], z["lum_trc"], z["sat_trc"])
    sig = read_signal(path, gamma)
    if cache is not None and digest:
        write_npz(cache, key=np.array(key), times=sig.times, lum_trc=sig.lum_trc, sat_trc=sig.sat_trc)
    return sig


def robust_sd(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if len(x) else 0.0


def find_steps(b_t: np.ndarray, min_snr: float = MIN_SNR) -> tuple[list[tuple[int, int, int]], float, float, float]:
    """Steps of the brightness signal: [(first jump i0, last jump i1, sign)] where jump i is
    b[i + 1] - b[i]; also the noise (robust sd of the jumps), the largest jump's SNR and its
    fraction of the mean brightness."""
    d_t = np.diff(b_t)
    level = max(float(np.median(b_t)), 1e-6)
    noise = max(robust_sd(d_t), 1e-7 * level)
    top = float(np.abs(d_t).max()) if len(d_t) else 0.0
    thr = max(min_snr * noise, STEP_FRACTION * top, MIN_RELATIVE_STEP * level)
    big = np.flatnonzero(np.abs(d_t) > thr)
    steps: list[tuple[int, int, int]] = []
    for i in big:
        s = int(np.sign(d_t[i]))
        if steps and steps[-1][2] == s and i - steps[-1][1] <= 2:
            steps[-1] = (steps[-1][0], int(i), s)
        else:
            steps.append((int(i), int(i), s))
    # a flash caught at the edge of an exposure leaves a small jump beside the big one: take it in
    weak = 3.0 * noise
    out = []
    for i0, i1, s in steps:
        while i0 > 0 and s * d_t[i0 - 1] > weak:
            i0 -= 1
        while i1 < len(d_t) - 1 and s * d_t[i1 + 1] > weak:
            i1 += 1
        out.append((i0, i1, s))
    return out, noise, top / noise, top / level


def time_step(sig: FlashSignal, i0: int, i1: int, sign: int, lo: int, hi: int, exposure_s: float | None,
              readout_s: float | None) -> FlashEvent | None:
    """Sub-frame time of the step whose jumps are i0..i1 (frames i0..i1 + 1 change), with the
    levels from frames lo..i0-1 (before) and i1+2..hi (after) (module docstring, step 3)."""
    lum, T = sig.lum_trc, len(sig.times)
    period = sig.period
    pre = np.arange(max(lo, i0 - 3), i0)
    post = np.arange(i1 + 2, min(hi, i1 + 5) + 1)
    if len(pre) == 0 or len(post) == 0:
        return None
    obs_k = np.arange(max(i0 - 1, 0), min(i1 + 3, T))
    pre_rc = np.median(lum[pre], axis=0)
    post_rc = np.median(lum[post], axis=0)
    dl_rc = post_rc - pre_rc
    # per-cell noise: the frame-to-frame differences of the steady frames before (else after) the step
    steady = pre if len(pre) > 1 else post
    cell_noise = robust_sd(np.diff(lum[steady], axis=0).ravel()) / np.sqrt(2) if len(steady) > 1 else 0.0
    cell_noise = max(cell_noise, 1e-6)
    window = np.r_[pre, obs_k, post]
    clipped_rc = sig.sat_trc[window].any(axis=0)
    # cells a person walks through change without the light: steady before and after, or left out
    tol_rc = 4.0 * cell_noise + 0.05 * np.abs(dl_rc)
    steady_rc = (np.abs(lum[pre] - pre_rc).max(axis=0) < tol_rc) & (np.abs(lum[post] - post_rc).max(axis=0) < tol_rc)
    use_rc = (sign * dl_rc > 4.0 * cell_noise) & ~clipped_rc & steady_rc
    if use_rc.sum() < 3:
        return None
    use_rc &= np.abs(dl_rc) >= 0.3 * np.median(np.abs(dl_rc[use_rc]))
    n_r = use_rc.sum(axis=1)
    rows_ok = n_r >= max(2, int(0.25 * lum.shape[2]))
    # lit fraction per transition frame and row band: the median over the row's cells (robust to a
    # cell a person moved in)
    with np.errstate(invalid="ignore", divide="ignore"):
        f_krc = np.where(use_rc, (lum[obs_k] - pre_rc) / dl_rc, np.nan)
        f_kr = np.nanmedian(np.where(rows_ok[None, :, None], f_krc, 0.0), axis=2)
    dl_r = np.sqrt((np.where(use_rc, dl_rc ** 2, 0.0)).sum(axis=1) / np.maximum(n_r, 1))
    energy_r = np.where(rows_ok, n_r * dl_r ** 2, 0.0)
    y_r = (np.arange(lum.shape[1]) + 0.5) / lum.shape[1]
    # observation noise of the fraction per row band: the cells' noise over the band's step
    sd_f_r = 1.25 * cell_noise / np.sqrt(np.maximum(energy_r, 1e-30))
    for edge in (F_EDGE, 0.2 * F_EDGE):  # near a level only when no frame shows more of the step
        edge_r = np.maximum(F_SIGMAS * sd_f_r, edge)
        part = longest_runs((f_kr > edge_r) & (f_kr < 1 - edge_r) & rows_ok[None])
        if part.any():
            break
    kk, rr = np.nonzero(part)
    t_k = sig.times[obs_k]
    e0 = exposure_s if exposure_s else 0.5 * period
    r0 = readout_s if readout_s is not None else 0.0
    if len(kk) == 0:
        # no partly lit row: the light changed between two exposures of the middle row
        if not rows_ok.any():
            return None
        last_pre = int(np.max(np.flatnonzero((f_kr[:, rows_ok].mean(axis=1) < 0.5)), initial=0))
        k = min(last_pre, len(obs_k) - 2)
        t = 0.5 * (t_k[k] + t_k[k + 1])
        return FlashEvent(t, sign, 0.0, (t_k[k + 1] - t_k[k] - e0) / np.sqrt(12), [int(x) for x in obs_k], 0, e0,
                          r0, {"note": "no partly lit frame: timed to the gap between two frames"})
    # the fraction is what is measured (the frame times are exact): f = 1/2 + a (t_k - t0) +
    # b (y - 1/2) - c with a = 1/e, b = R/e, c = (t_f - t0)/e, linear in (a, b, c)
    t0 = float(t_k[kk].mean())
    A = np.column_stack([t_k[kk] - t0, y_r[rr] - 0.5, -np.ones(len(kk))])
    f = f_kr[kk, rr] - 0.5
    w = 1.0 / np.maximum(sd_f_r[rr], 1e-4)
    # priors: e and R as given (tight) or as assumed (loose: the data decide when they can)
    a0, b0 = 1.0 / e0, r0 / e0
    sd_a = 1e-3 * a0 if exposure_s else 0.5 * a0
    sd_b = 1e-3 * max(abs(b0), 1.0) if readout_s is not None else period / e0
    prior_A = np.array([[1 / sd_a, 0, 0], [0, 1 / sd_b, 0]])
    prior_b = np.array([a0 / sd_a, b0 / sd_b])
    keep = np.ones(len(kk), bool)
    s_res = 0.01
    for _ in range(5):  # drop observations a moving person spoiled; weights from the actual scatter
        w = 1.0 / np.maximum(sd_f_r[rr], s_res)
        M = np.vstack([A[keep] * w[keep, None], prior_A])
        x, *_ = np.linalg.lstsq(M, np.r_[f[keep] * w[keep], prior_b], rcond=None)
        res = A @ x - f
        s_res = max(robust_sd(res[keep]) if keep.sum() > 3 else 0.0, 0.003)
        new = np.abs(res) < 4.0 * s_res
        if (new == keep).all() or new.sum() < 2:
            break
        keep = new
    a, b, c = (float(v) for v in x)
    if not a > 0:
        return None
    t_f = t0 + c / a
    w = 1.0 / np.maximum(sd_f_r[rr], s_res)
    M = np.vstack([A[keep] * w[keep, None], prior_A])
    cov = np.linalg.pinv(M.T @ M)
    J = np.array([-c / a ** 2, 0.0, 1.0 / a])
    sd = float(np.sqrt(max(J @ cov @ J, 0.0)))
    return FlashEvent(t_f, sign, 0.0, sd, [int(v) for v in obs_k], int(keep.sum()), 1.0 / a, b / a,
                      {"rows_lit": int(rows_ok.sum()),
                       "fraction_residual_rms": round(float(np.sqrt(np.mean(res[keep] ** 2))), 5)})


def longest_runs(part_kr: np.ndarray) -> np.ndarray:
    """Per frame, only the longest run of consecutive partly lit rows: a rolling shutter lights rows in
    order, so a lone row elsewhere is a moving person or the encoder, not the light."""
    from scipy import ndimage

    out = np.zeros_like(part_kr)
    for k, row in enumerate(part_kr):
        lab, n = ndimage.label(row)
        if n:
            sizes = np.bincount(lab)[1:]
            out[k] = lab == 1 + int(np.argmax(sizes))
    return out


def camera_events(sig: FlashSignal, cfg: Mapping) -> tuple[list[FlashEvent], dict]:
    """Every flash step in one camera's signal, timed (module docstring, steps 2-3)."""
    steps, noise, snr_top, rel_top = find_steps(sig.b_t, float(cfg.get("min_snr", MIN_SNR)))
    exposure = float(cfg.get("exposure_s") or 0.0) or None
    readout = cfg.get("readout_s")
    readout = None if readout in (None, "") else float(readout)
    d_t = np.diff(sig.b_t)
    spans = [(i0, i1, s, steps[j - 1][1] + 2 if j else 0,
              steps[j + 1][0] - 1 if j + 1 < len(steps) else len(sig.times) - 1) for j, (i0, i1, s) in enumerate(steps)]
    timed = [time_step(sig, i0, i1, s, lo, hi, exposure, readout) for i0, i1, s, lo, hi in spans]
    # one camera keeps its exposure and readout through the take: steps that few rows caught are
    # timed again with the camera's values from the steps that many rows caught
    rich = [e for e in timed if e is not None and e.observations >= POOL_MIN_OBSERVATIONS]
    if rich and (exposure is None or readout is None):
        w = np.array([e.observations for e in rich], float)
        e_cam = exposure or float(np.average([e.exposure_s for e in rich], weights=w))
        r_cam = readout if readout is not None else float(np.average([e.readout_s for e in rich], weights=w))
        timed = [time_step(sig, *span[:3], *span[3:], e_cam, r_cam)
                 if ev is not None and ev.observations < POOL_MIN_OBSERVATIONS else ev for ev, span in zip(timed, spans)]
    events = []
    for ev, (i0, i1, *_) in zip(timed, spans):
        if ev is not None:
            ev.snr = float(abs(d_t[i0:i1 + 1].sum()) / noise)
            events.append(ev)
    return events, {"noise": noise, "largest_jump_snr": round(float(snr_top), 2),
                    "largest_jump_percent": round(100 * float(rel_top), 2), "steps": len(steps)}


def match_events(ref: list[FlashEvent], cam: list[FlashEvent], period: float, max_rate: float = 300e-6
                 ) -> list[tuple[int, int]]:
    """Pairs (i in ref, j in cam) of the same flashes: the shift t_ref - t_cam that pairs the most
    steps of the same sign (within a few frames plus what drift allows), then the closest."""
    if not ref or not cam:
        return []
    t_r = np.array([e.t for e in ref])
    t_c = np.array([e.t for e in cam])
    s_r = np.array([e.sign for e in ref])
    s_c = np.array([e.sign for e in cam])
    span = max(np.ptp(t_r), np.ptp(t_c), 1.0)
    tol = 2.0 * period + max_rate * span
    best: tuple = (0, np.inf, [])
    for i in range(len(ref)):
        for j in np.flatnonzero(s_c == s_r[i]):
            shift = t_r[i] - t_c[j]
            gap = np.abs(t_r[:, None] - (t_c[None] + shift))
            gap[s_r[:, None] != s_c[None]] = np.inf
            pairs, err = [], 0.0
            used = set()
            for a in np.argsort(gap.min(axis=1)):
                b = int(np.argmin(gap[a]))
                if gap[a, b] <= tol and b not in used:
                    pairs.append((int(a), b))
                    used.add(b)
                    err += gap[a, b] ** 2
            if (len(pairs), -err) > (best[0], -best[1]):
                best = (len(pairs), err, pairs)
    return sorted(best[2])


def flash_clocks(signals: Mapping[str, FlashSignal], reference: str, cfg: Mapping | None = None,
                 names: Mapping[str, str] | None = None) -> tuple[dict[str, ClockModel], dict, list[str]]:
    """Every camera's clock relative to ``reference`` from its flashes. ``cfg``: DEFAULTS' keys;
    exposure_s (0: unknown) and readout_s (absent: unknown) may be tables camera -> seconds.
    ``names``: camera -> the file name to say in messages. -> (clocks, per-camera diagnostics, warnings)."""
    from mamma_kit.timing.fit import robust_line

    cfg = {**DEFAULTS, **(cfg or {})}
    names = dict(names or {})
    found, diag = {}, {}
    for n, sig in signals.items():
        # exposure and readout: one for all cameras, or a table camera -> seconds
        own = {k: (v.get(n) if isinstance(v, Mapping) else v) for k, v in cfg.items()}
        evs, info = camera_events(sig, own)
        found[n] = evs
        diag[n] = {"flashes": [{"t_s": round(e.t, 6), "sign": "on" if e.sign > 0 else "off",
                                "snr": round(e.snr, 1), "precision_ms": round(e.precision_s * 1e3, 3),
                                "frames": e.frames, "observations": e.observations,
                                "exposure_ms": round(e.exposure_s * 1e3, 3), "readout_ms": round(e.readout_s * 1e3, 3),
                                **e.info} for e in evs], "largest_jump_snr": info["largest_jump_snr"],
                   "largest_jump_percent": info["largest_jump_percent"]}
    missing = [n for n in signals if not found[n]]
    if missing:
        seen = [n for n in signals if found[n]]
        why = "; ".join(f"{names.get(n, n)}: its largest brightness jump is {diag[n]['largest_jump_snr']:.1f}x the "
                        f"frame-to-frame noise and {diag[n]['largest_jump_percent']:.2f} % of the image's brightness "
                        f"(a flash needs {float(cfg['min_snr']):.0f}x and {100 * MIN_RELATIVE_STEP:.0f} %)"
                        for n in missing)
        raise UserError(f"no flash found in {', '.join(names.get(n, n) for n in missing)} ({why}"
                        + (f"; seen by {', '.join(seen)}" if seen else "") + ")",
                        "switch a light on or flash a phone torch where every camera sees it light a good part of "
                        "the image (a second of steady light before and after), or sync by --method clap, ltc, "
                        "tmcd or motion")
    warnings: list[str] = []
    clocks: dict[str, ClockModel] = {}
    ref_ev = found[reference]
    for n, evs in found.items():
        period = signals[n].period
        if n == reference:
            clocks[n] = ClockModel(0.0, 0.0, "flash", 1.0)
            pairs = [(i, i) for i in range(len(evs))]
        else:
            pairs = match_events(ref_ev, evs, period)
            if not pairs:
                raise UserError(f"the flashes in {names.get(n, n)} do not match those of {names.get(reference, reference)} "
                                f"({len(evs)} vs {len(ref_ev)} steps, none of the same kind at a consistent shift)",
                                "flash where every camera sees it, or sync by another --method")
            t_c = np.array([evs[j].t for _, j in pairs])
            t_r = np.array([ref_ev[i].t for i, _ in pairs])
            sd = np.array([np.hypot(evs[j].precision_s, ref_ev[i].precision_s) for i, j in pairs])
            w = 1.0 / np.maximum(sd, 1e-5) ** 2
            if len(pairs) >= 3 and np.ptp(t_c) >= DRIFT_MIN_SPAN_S:
                fit = robust_line(t_c, t_r, w, scale_floor=2e-4)
                rate, off = fit.slope - 1.0, fit.intercept
                resid = fit.residual_n
            else:
                off = float(np.sum(w * (t_r - t_c)) / np.sum(w))
                rate = 0.0
                resid = t_r - t_c - off
            prec = float(1.0 / np.sqrt(np.sum(w)))
            snr = min(min(evs[j].snr, ref_ev[i].snr) for i, j in pairs)
            # confidence: the timing's precision against a quarter frame, and the step's strength
            conf = float(np.clip(1.0 - prec / (0.25 * period), 0.0, 1.0) * np.clip(snr / (4 * float(cfg["min_snr"])),
                                                                                    0.0, 1.0))
            clocks[n] = ClockModel(float(off), float(rate), "flash", round(conf, 4))
            diag[n]["residuals_ms"] = [round(float(r) * 1e3, 4) for r in resid]
            diag[n]["precision_ms"] = round(prec * 1e3, 4)
            if len(pairs) < len(evs) or len(pairs) < len(ref_ev):
                warnings.append(f"{n}: {len(pairs)} of its {len(evs)} flash steps matched the reference's "
                                f"{len(ref_ev)}")
        diag[n]["matched"] = [[int(i), int(j)] for i, j in pairs]
    return clocks, diag, warnings
