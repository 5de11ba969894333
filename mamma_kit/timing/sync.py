"""Synchronise a set of camera videos: read their audio / timecode, run the methods, cross-check.

``sync_videos`` is what ``mamma-kit sync`` calls. Methods:
- ``ltc``: an LTC timecode signal on an audio channel of every camera (decoded per frame,
  offset + drift by a line fit); the timecode is a common clock.
- ``clap``: claps heard by the cameras (onsets + GCC-PHAT + joint solve), optionally
  corrected for sound travel when clap and microphone positions are known.
- ``tmcd``: the start timecode of each file (whole frame, no drift).
- ``flash``: a light switched on or a torch flashed in view of every camera (timing.flash).
- ``motion``: the people's keypoints and the calibration (timing.motion; a workspace after
  track + keypoints).
- ``synced`` / ``timestamps``: cameras on one clock, or a file of every frame's time (timing.given).
- ``auto``: every method the files allow (the timestamps file when given, LTC and claps when
  there is audio, tmcd, flash, and motion when the workspace has keypoints and a calibration);
  the most precise one that works on every camera wins (AUTO_ORDER); the others cross-check it
  at the times they share evidence: a disagreement beyond tolerance is an error, tmcd beyond a
  frame a warning; diagnostics["agreement"] sums it up per method pair.
All clocks are relative to the reference camera (offset 0, rate 0).
"""

from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass, field
from math import gcd
from pathlib import Path
from typing import Mapping

import numpy as np
from scipy import signal

from mamma_kit.core import log
from mamma_kit.core.clock import ClockModel
from mamma_kit.core.errors import UserError
from mamma_kit.timing.clap import ClapResult, ClapSettings, Track, clap_sync
from mamma_kit.timing.fit import relative_clock
from mamma_kit.timing.ltc import LtcClock, find_ltc_channel, looks_like_ltc, ltc_clock
from mamma_kit.timing.tmcd import TmcdClock, tmcd_clock

METHODS = ("auto", "clap", "ltc", "tmcd", "synced", "timestamps", "motion", "flash")
# auto's preference where several methods work on every camera: a logged clock, then LTC (sub-sample),
# claps (sub-millisecond), a flash (a few ms), motion (a few ms, needs people), tmcd (whole frames)
AUTO_ORDER = ("timestamps", "ltc", "clap", "flash", "motion", "tmcd")
PRESET_DIR = Path(__file__).resolve().parents[2] / "sync"

DEFAULTS: dict = {
    "method": "auto",
    "clap": {},
    "ltc": {"fps": 0.0, "min_fraction": 0.5},
    "flash": {"exposure_s": 0.0, "gamma": 2.2, "min_snr": 8.0},
    # what each method's offsets may be off by, added to the agreement tolerance when it is compared
    "check": {"agreement_tolerance_ms": 5.0, "max_travel_ms": 30.0, "estimated_travel_ms": 10.0,
              "flash_tolerance_ms": 4.0, "motion_tolerance_ms": 4.0},
    # a CSV of every frame's time on the rig's clock (method "timestamps"; auto uses it when given)
    "timestamps": "",
}


# ---------------------------------------------------------------------------------------
# settings and presets
def _merge(base: dict, over: Mapping) -> dict:
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        if isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.toml")) if PRESET_DIR.is_dir() else []


def load_settings(preset: str | Path | None = None, overrides: Mapping | None = None) -> dict:
    """Defaults <- preset (a name from sync/ or a TOML file) <- overrides (capture.toml's
    [settings.sync], then the command line)."""
    s = copy.deepcopy(DEFAULTS)
    if preset:
        p = Path(preset)
        if not p.is_file():
            p = PRESET_DIR / f"{preset}.toml"
        if not p.is_file():
            raise UserError(f"unknown sync preset '{preset}'",
                            f"use one of {', '.join(preset_names()) or '(none found)'} or a path to a TOML file")
        try:
            data = tomllib.loads(p.read_text())
        except tomllib.TOMLDecodeError as e:
            raise UserError(f"sync preset {p} is not valid TOML ({e})", "fix the syntax at that line") from None
        s = _merge(s, data)
    s = _merge(s, overrides or {})
    if s.get("method", "auto") not in METHODS:
        raise UserError(f"unknown sync method '{s['method']}'", f"use one of {', '.join(METHODS)}")
    return s


# ---------------------------------------------------------------------------------------
@dataclass
class CameraMedia:
    name: str
    path: Path
    timestamps: np.ndarray
    nominal_fps: float
    timecode: str | None
    audio: object | None = None        # mamma_kit.video.Audio
    audio_error: UserError | None = None


@dataclass
class SyncResult:
    clocks: dict[str, ClockModel]
    reference: str
    method: str
    diagnostics: dict
    camera_diagnostics: dict[str, dict]
    warnings: list[str]
    by_method: dict[str, dict[str, ClockModel]] = field(default_factory=dict)
    clap: ClapResult | None = None
    ltc: dict[str, LtcClock] | None = None
    tmcd: dict[str, TmcdClock] | None = None
    frame_times: dict[str, np.ndarray] = field(default_factory=dict)

    def summary(self) -> dict:
        return {"reference": self.reference, "method": self.method, "cameras": {
            n: {"offset_s": c.offset, "rate_ppm": c.rate_ppm, "method": c.source, "confidence": c.confidence}
            for n, c in self.clocks.items()}, "warnings": self.warnings, "diagnostics": self.diagnostics}


def load_media(videos: Mapping[str, Path], need_audio: bool) -> dict[str, CameraMedia]:
    from mamma_kit.video import VideoReader, read_audio

    media = {}
    for name, path in log.track(list(videos.items()), "reading videos"):
        info = VideoReader(path).info
        m = CameraMedia(name, Path(path), info.timestamps, info.nominal_fps, info.timecode)
        if need_audio:
            try:
                m.audio = read_audio(path)
            except UserError as e:
                m.audio_error = e
        media[name] = m
    return media


def _check_audible(m: CameraMedia) -> None:
    if m.audio is None:
        raise m.audio_error or UserError(f"{m.path.name} has no audio stream", "record with sound on")
    peak = float(np.abs(m.audio.samples_nc).max()) if m.audio.n_samples else 0.0
    if peak < 1e-4:
        db = 20 * np.log10(max(peak, 1e-12))
        raise UserError(f"the audio of {m.path.name} is silent (peak {db:.0f} dBFS)",
                        "check the microphone was on and not muted, or sync by --method tmcd")


# ---------------------------------------------------------------------------------------
def sync_videos(videos: Mapping[str, Path], method: str = "auto", reference: str | None = None,
                settings: Mapping | None = None, clap_positions=None,
                mic_positions: Mapping[str, np.ndarray] | None = None, motion=None,
                flash_cache: Path | None = None) -> SyncResult:
    """``motion``: (keypoints per camera, rig) for --method motion, and for auto when the workspace
    has them (the workspace stage loads them). ``flash_cache``: a folder keeping each video's
    brightness signal (decoding is the slow part of flash sync; kept when a later step fails)."""
    st = load_settings(None, settings)
    if method not in METHODS:
        raise UserError(f"unknown sync method '{method}'", f"use one of {', '.join(METHODS)}")
    names = list(videos)
    if len(names) < 2:
        raise UserError("sync needs at least two cameras", "pass two or more videos, or a workspace with several")
    reference = reference or names[0]
    if reference not in videos:
        raise UserError(f"reference camera '{reference}' is not among {', '.join(names)}",
                        "pass one of those names to --reference")
    if method == "timestamps" and not st.get("timestamps"):
        raise UserError("--method timestamps needs the file of frame times", "pass --timestamps FILE")
    media = load_media(videos, need_audio=method in ("auto", "clap", "ltc"))
    if method in ("synced", "timestamps", "motion", "flash"):
        return _given(media, method, reference, st, motion, flash_cache)
    warnings: list[str] = []
    by_method: dict[str, dict[str, ClockModel]] = {}
    failures: dict[str, UserError] = {}
    cam_diag: dict[str, dict] = {n: {} for n in names}
    ltc_res = clap_res = tmcd_res = None

    audio_ok = method in ("auto", "clap", "ltc") and all(m.audio is not None for m in media.values())
    if method in ("clap", "ltc"):
        for m in media.values():
            _check_audible(m)
    elif audio_ok:
        try:
            for m in media.values():
                _check_audible(m)
        except UserError as e:
            failures["audio"] = e
            audio_ok = False
    elif method == "auto":
        failures["audio"] = next(m.audio_error for m in media.values() if m.audio is None)

    # --- LTC
    ltc_channels: dict[str, int] = {}
    if method == "ltc" or (method == "auto" and audio_ok):
        try:
            ltc_res = _run_ltc(media, reference, st["ltc"], ltc_channels)
            by_method["ltc"] = {n: _rel(ltc_res[n].clock, ltc_res[reference].clock, "ltc",
                                        min(ltc_res[n].fraction, ltc_res[reference].fraction)) for n in names}
            for n in names:
                lc = ltc_res[n]
                cam_diag[n]["ltc"] = {
                    "channel": ltc_channels[n], "fps": lc.fps_name, "drop_frame": lc.drop_frame,
                    "decoded_frames": lc.decoded, "expected_frames": lc.expected,
                    "decoded_fraction": round(lc.fraction, 5), "first_timecode": lc.first_tc,
                    "last_timecode": lc.last_tc, "user_bits": f"{lc.user_bits:08x}",
                    "residual_rms_samples": round(float(lc.fit.rms * media[n].audio.sample_rate), 4),
                    "timecode_offset_s": lc.clock.offset, "timecode_rate_ppm": lc.clock.rate_ppm,
                    "reversed_frames": lc.reversed_frames,
                }
        except UserError as e:
            if method == "ltc":
                raise
            failures["ltc"] = e

    # --- clap
    if method == "clap" or (method == "auto" and audio_ok):
        try:
            clap_res = _run_clap(media, reference, st["clap"], ltc_channels, clap_positions, mic_positions)
            by_method["clap"] = clap_res.clocks
            if not clap_res.diagnostics.get("sound_travel_corrected") and len(clap_res.events_t) > 1:
                warnings.append("clap sound travel not corrected (no clap positions and no calibration): offsets "
                                "carry up to 2.9 ms per metre between the camera distances, and claps made at "
                                "different spots bias the drift; clap from one spot, or add calibration.toml")
            for n in names:
                d = dict(clap_res.camera_diagnostics[n])
                mine = [o for o in clap_res.observations if reference in (o.i, o.j) and n in (o.i, o.j) and n != reference]
                # the reference camera's time of each event this camera shares with it
                d["event_times_s"] = [round(o.t_i if o.i == reference else o.t_j, 6) for o in mine]
                d["residuals_ms"] = [round(o.residual_s * 1e3, 5) for o in mine]
                d["psr"] = [round(o.psr, 2) for o in mine]
                cam_diag[n]["clap"] = d
        except UserError as e:
            if method == "clap":
                raise
            failures["clap"] = e

    # --- tmcd
    have_tc = all(m.timecode for m in media.values())
    if method == "tmcd" and not have_tc:
        missing = [m.path.name for m in media.values() if not m.timecode]
        raise UserError(f"no tmcd timecode track in {', '.join(missing)}",
                        "record with timecode on, or sync by --method clap/ltc")
    if have_tc and method in ("auto", "tmcd", "clap", "ltc"):
        tmcd_res = {n: tmcd_clock(m.timecode, m.nominal_fps, float(m.timestamps[0])) for n, m in media.items()}
        by_method["tmcd"] = {n: _rel(tmcd_res[n].clock, tmcd_res[reference].clock, "tmcd", tmcd_res[n].clock.confidence)
                             for n in names}
        for n in names:
            cam_diag[n]["tmcd"] = {"timecode": tmcd_res[n].timecode, "fps": tmcd_res[n].fps_name}

    # --- the methods that need no audio (auto tries each the files allow)
    evidence: dict[str, dict[str, list[float]]] = {}
    if method == "auto":
        tried = (["timestamps"] if st.get("timestamps") else []) + ["flash"] + (["motion"] if motion is not None else [])
        for k in tried:
            try:
                clocks_k, diag_k, warn_k = _video_method(media, k, reference, st, motion, flash_cache)
            except UserError as e:
                failures[k] = e
                continue
            by_method[k] = clocks_k
            warnings.extend(warn_k)
            for n in names:
                cam_diag[n][k] = diag_k.get(n, {})
            if k == "flash":  # flash offsets are exact at the flashes (drift aside)
                evidence["flash"] = {n: [f["t_s"] for f in diag_k[n]["flashes"]] for n in names}
        if "motion" not in tried:
            failures["motion"] = UserError("no keypoints/ and calibration.toml in the workspace")

    # --- choose
    order = [method] if method != "auto" else list(AUTO_ORDER)
    chosen = next((k for k in order if k in by_method), None)
    if chosen is None:
        reasons = "; ".join(f"{k}: {e.message}" for k, e in failures.items())
        raise UserError(f"no sync method worked on every camera ({reasons or 'no audio and no timecode'})",
                        "record a clap or LTC on every camera's audio, timecode (tmcd), or flash a light in view "
                        "of every camera; or sync by --method synced / --timestamps FILE for a rig on one clock")
    clocks = {n: copy.deepcopy(c) for n, c in by_method[chosen].items()}
    clocks[reference] = ClockModel(0.0, 0.0, chosen, 1.0)

    # --- agreement between methods
    agreement = _agreement(by_method, media, chosen, st["check"], clap_res, warnings, reference, evidence)
    for n in names:
        c = clocks[n]
        cam_diag[n]["offset_ms"] = round(c.offset * 1e3, 6)
        cam_diag[n]["drift_ppm"] = round(c.rate_ppm, 4)
        if n in agreement:
            cam_diag[n]["agreement_ms"] = agreement[n]
    for w in warnings:
        log.warn(w)
    not_used = {k: e.message for k, e in failures.items()}
    for k, msg in not_used.items():
        log.info(f"{k} not used: {msg}")
    diag = {"methods_tried": sorted(set(by_method) | set(failures)), "methods_ok": sorted(by_method),
            "chosen": chosen}
    summary = agreement_summary(agreement)
    if summary:
        diag["agreement"] = summary
        for pair, d in summary.items():
            log.info(f"{pair}: the clocks agree within {d['max_abs_ms']:.3f} ms (rms {d['rms_ms']:.3f} ms, "
                     f"{d['cameras']} cameras)")
    if method == "auto":
        log.info(f"sync: {chosen} chosen of {', '.join(sorted(by_method))} (auto order: {' > '.join(AUTO_ORDER)})")
    if clap_res is not None:
        diag["clap"] = clap_res.diagnostics
    if warnings:
        diag["warnings"] = warnings
    if not_used:
        diag["not_used"] = not_used
    return SyncResult(clocks, reference, chosen, diag, cam_diag, warnings, by_method, clap_res, ltc_res, tmcd_res,
                      {n: m.timestamps for n, m in media.items()})


def _video_method(media: Mapping[str, CameraMedia], method: str, reference: str, st: Mapping, motion=None,
                  flash_cache: Path | None = None) -> tuple[dict[str, ClockModel], dict, list[str]]:
    """One method that needs no audio -> (clocks, per-camera diagnostics, warnings)."""
    from mamma_kit.timing.given import synced_clocks, timestamp_clocks

    stamps = {n: m.timestamps for n, m in media.items()}
    if method == "synced":
        return synced_clocks(stamps)
    if method == "motion":
        from mamma_kit.timing.motion import motion_clocks

        if motion is None:
            raise UserError("--method motion needs a workspace with keypoints/ and calibration.toml",
                            "run `mamma-kit sync WORKSPACE --method motion` after `track` and `keypoints`")
        kts, rig = motion
        return motion_clocks(kts, rig, reference, float(st.get("motion_max_lag_s", 2.0)))
    if method == "flash":
        return _run_flash(media, reference, st.get("flash", {}), flash_cache)
    clocks, cam_diag = timestamp_clocks(stamps, Path(st["timestamps"]), reference)
    return clocks, cam_diag, []


def _run_flash(media, reference, cfg, cache_dir) -> tuple[dict[str, ClockModel], dict, list[str]]:
    from mamma_kit.core.manifest import FileHasher
    from mamma_kit.timing.flash import flash_clocks, load_signal

    hasher = FileHasher(None) if cache_dir is not None else None
    gamma = float(cfg.get("gamma", 2.2))
    signals = {}
    for n, m in log.track(list(media.items()), "flash: reading brightness"):
        cache = Path(cache_dir) / f"{n}.npz" if cache_dir is not None else None
        signals[n] = load_signal(m.path, cache, hasher(m.path) if hasher else None, gamma)
    return flash_clocks(signals, reference, cfg, {n: m.path.name for n, m in media.items()})


def _given(media: Mapping[str, CameraMedia], method: str, reference: str, st: Mapping, motion=None,
           flash_cache: Path | None = None) -> SyncResult:
    """Clocks without audio: one shared clock, a file of every frame's time, a flash, or the
    people's motion."""
    stamps = {n: m.timestamps for n, m in media.items()}
    clocks, cam_diag, warnings = _video_method(media, method, reference, st, motion, flash_cache)
    for w in warnings:
        log.warn(w)
    diag = {"methods_tried": [method], "methods_ok": [method], "chosen": method}
    if method == "timestamps":
        diag["timestamps_file"] = str(st["timestamps"])
    if warnings:
        diag["warnings"] = warnings
    for n, c in clocks.items():
        cam_diag[n]["offset_ms"] = round(c.offset * 1e3, 6)
        cam_diag[n]["drift_ppm"] = round(c.rate_ppm, 4)
    return SyncResult(clocks, reference, method, diag, cam_diag, warnings, {method: clocks},
                      frame_times=dict(stamps))


def _rel(cam: ClockModel, ref: ClockModel, source: str, confidence: float) -> ClockModel:
    off, rate = relative_clock(cam, ref)
    return ClockModel(off, rate, source, round(float(confidence), 4))


def _run_ltc(media, reference, cfg, channels_out) -> dict[str, LtcClock]:
    fps = float(cfg.get("fps") or 0.0) or None
    out = {}
    for n, m in media.items():
        a = m.audio
        found = find_ltc_channel(a.samples_nc, a.sample_rate, fps)
        lc = ltc_clock(found[1], a.start_s, a.duration, fps) if found else None
        if lc is None or lc.decoded < 2 or lc.fraction < float(cfg.get("min_fraction", 0.5)):
            frac = f" ({lc.decoded} of {lc.expected} frames decoded)" if lc else ""
            raise UserError(
                f"no LTC found in {m.path.name}{frac}: looked at audio channel(s) 0-{a.n_channels - 1} for a "
                f"biphase-mark timecode signal at 23.976-30 words/s",
                "connect the timecode generator to that camera's audio input, or sync by --method clap/tmcd")
        channels_out[n] = found[0]
        out[n] = lc
    return out


def _run_clap(media, reference, cfg, ltc_channels, clap_positions, mic_positions) -> ClapResult:
    st = ClapSettings.from_dict(cfg)
    sr = media[reference].audio.sample_rate
    tracks = {}
    for n, m in media.items():
        a = m.audio
        if n in ltc_channels:
            chans = [c for c in range(a.n_channels) if c != ltc_channels[n]]
        else:  # LTC not decoded (e.g. --method clap): still keep timecode channels out of the mix
            chans = [c for c in range(a.n_channels) if not looks_like_ltc(a.samples_nc[:, c])]
        if not chans:
            raise UserError(f"{m.path.name} has only the LTC channel: no microphone sound to find claps in",
                            "sync by --method ltc")
        x = a.samples_nc[:, chans].mean(axis=1).astype(np.float64)
        if a.sample_rate != sr:
            g = gcd(int(sr), int(a.sample_rate))
            x = signal.resample_poly(x, sr // g, a.sample_rate // g)
        tracks[n] = Track(n, x, sr, a.start_s, chans[0], m.path.name)
    if clap_positions is not None and mic_positions is None:
        raise UserError("clap positions are set but there is no calibration to place the microphones",
                        "calibrate first (calibration.toml), or drop clap_positions")
    return clap_sync(tracks, reference, st, clap_positions, mic_positions)


def _agreement(by_method, media, chosen, check, clap_res, warnings, reference, evidence=None) -> dict[str, dict]:
    """Per camera: mapping difference (ms) between each other method and the chosen one, where
    their evidence lies: at the claps when claps are involved, at the flashes when a flash is,
    else at mid-take."""
    out: dict[str, dict] = {}
    evidence = dict(evidence or {})
    base = by_method[chosen]
    tol = float(check.get("agreement_tolerance_ms", 5.0))
    # what the clap offsets may still carry of the sound's travel: nothing with known clap
    # positions; with positions estimated from the clocks (one clap leaves them nearly free),
    # up to estimated_travel_ms; uncorrected, up to max_travel_ms
    where = clap_res.diagnostics.get("clap_positions") if clap_res is not None else None
    travel = 0.0 if where == "known" else float(check.get("estimated_travel_ms", 10.0)) if where == "estimated" \
        else float(check.get("max_travel_ms", 30.0))
    if clap_res is not None:
        evidence["clap"] = {n: [o.t_i if o.i == n else o.t_j for o in clap_res.observations if n in (o.i, o.j)]
                            for n in media}
    # the looser methods' own allowance
    allow = {"flash": float(check.get("flash_tolerance_ms", 4.0)), "motion": float(check.get("motion_tolerance_ms", 4.0))}
    for k, cl in by_method.items():
        if k == chosen:
            continue
        for n, m in media.items():
            if n == reference:
                continue
            tm = float(np.median(m.timestamps))
            for src in ("clap", "flash"):
                if src in (k, chosen) and evidence.get(src, {}).get(n):
                    # compare where that method gives evidence (one clap or flash: no drift, exact only there)
                    tm = float(np.median(evidence[src][n]))
                    break
            diff_ms = float(cl[n].to_ref(tm) - base[n].to_ref(tm)) * 1e3
            out.setdefault(n, {})[f"{k}-{chosen}"] = round(diff_ms, 4)
            if "tmcd" in (k, chosen):
                frame_ms = 1e3 / max(m.nominal_fps, 1.0)
                lim = frame_ms + (travel if "clap" in (k, chosen) else 0.0) + sum(allow.get(x, 0.0) for x in (k, chosen))
                if abs(diff_ms) > lim:
                    warnings.append(f"{n}: tmcd and {chosen if k == 'tmcd' else k} disagree by {diff_ms:+.1f} ms "
                                    f"(more than a frame, {frame_ms:.1f} ms): the start timecode is not to be trusted")
            else:
                lim = tol + (travel if "clap" in (k, chosen) else 0.0) + sum(allow.get(x, 0.0) for x in (k, chosen))
                if abs(diff_ms) > lim and {k, chosen} & set(allow):
                    # a flash or motion cross-check can be fooled by the scene (a lamp, auto exposure, a
                    # wrong person pairing): said, not fatal
                    warnings.append(f"{n}: {k} and {chosen} disagree by {diff_ms:+.2f} ms (tolerance {lim:.1f} ms): "
                                    f"check that camera's {k if k in allow else chosen} diagnostics")
                elif abs(diff_ms) > lim:
                    raise UserError(
                        f"{k} and {chosen} clocks disagree on {n} by {diff_ms:+.2f} ms (tolerance {lim:.1f} ms)",
                        "check that all timecode boxes were jammed from one source and the claps were heard by "
                        f"every camera, then pick one method with --method {chosen}|{k} (or raise "
                        "check.agreement_tolerance_ms in the preset)")
    return out


def agreement_summary(agreement: Mapping[str, Mapping[str, float]]) -> dict[str, dict]:
    """Per method pair ("flash-clap"): the largest and rms difference over the cameras (ms)."""
    pairs: dict[str, list[float]] = {}
    for per in agreement.values():
        for pair, ms in per.items():
            pairs.setdefault(pair, []).append(float(ms))
    return {p: {"max_abs_ms": round(float(np.max(np.abs(v))), 4), "rms_ms": round(float(np.sqrt(np.mean(np.square(v)))), 4),
                "cameras": len(v)} for p, v in pairs.items()}
