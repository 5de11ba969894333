"""The landmarks stage: masks/<cam>.npz + videos -> landmarks/<cam>.npz.

``run_landmarks`` is what `mamma-kit landmarks WORKSPACE` and capture-to-smplx call. With
``source="net"`` MammaNet predicts the landmarks of every tracked person; ``source="gt"``
writes a synthetic workspace's ground truth with noise (to test later stages alone). Each
camera is a unit with its own manifest (.cache/landmarks-<cam>.json), so an interrupted
run keeps the cameras it finished.
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.manifest import StageManifest, producer


def _camera_names(ws, only, fallback_dir: Path | None = None) -> list[str]:
    from mamma_kit.core.workspace import select_cameras

    if ws.capture_toml.is_file():
        names = ws.load_capture().camera_names
    elif fallback_dir is not None and fallback_dir.is_dir():
        names = sorted(p.stem for p in fallback_dir.glob("*.npz"))
    else:
        names = []
    names = select_cameras(names, only)
    if not names:
        raise UserError(f"{ws.root} lists no cameras", "check capture.toml")
    return names


def run_landmarks(ws, *, source: str = "net", weights: Path | str | None = None, arch: str | None = None,
                  batch: int = 8, device: str = "cpu", cameras: list[str] | str | None = None, noise: str = "0",
                  outliers: float = 0.0, seed: int = 0, force: bool = False, loaded=None,
                  unit_frames: int | None = None, hands: str | Path | None = "auto",
                  smooth_s: float | None = None, contact: str | Path | None = "auto") -> dict:
    """Landmarks for every tracked person of every camera (see the module docstring).
    ``loaded``: an already loaded model (mamma_kit.landmarks.weights.load_model). ``unit_frames``:
    frames per unit of work (0: a camera per unit; None: MAMMA_KIT_UNIT_FRAMES). ``hands``: the hand
    refinement (landmarks/hands.py): "auto" (the shipped HandNet where it fits the model), "off" or
    a weights path. ``smooth_s``: the network's contact and visibility smoothed over this many
    seconds (landmarks/smooth.py; None: SMOOTH_S, 0: off). ``contact``: the network whose
    person-contact head is used (``contact_network``): "auto", "off" or a weights path."""
    if source not in ("net", "gt"):
        raise UserError(f"--source '{source}' is unknown", "use --source net or --source gt")
    if source == "net" and loaded is None:
        from mamma_kit.landmarks.weights import load_model

        loaded = load_model(weights, arch, device)
    t0 = time.perf_counter()
    refiner = contact_loaded = None
    if source == "gt":
        from mamma_kit.landmarks.gt import gt_landmarks_file, gt_masks_file

        cams = _camera_names(ws, cameras, ws.gt_dir / "landmarks")
        unit_inputs = {c: [p for p in (gt_landmarks_file(ws, c), gt_masks_file(ws, c), ws.mask_file(c)) if p.exists()]
                       for c in cams}
        settings = {"source": "gt", "noise": noise, "outliers": outliers, "seed": seed}
    else:
        cams = _camera_names(ws, cameras)
        cap = ws.load_capture()
        missing = [c for c in cams if not ws.mask_file(c).is_file()]
        if missing:
            raise UserError(f"no person masks for {', '.join(missing)} (masks/<cam>.npz)",
                            "run `mamma-kit track WORKSPACE` first")
        unit_inputs = {c: [ws.mask_file(c), cap.cameras[c].video, Path(loaded.source)] for c in cams}
        if loaded.config.keypoints_in:
            missing = [c for c in cams if not ws.keypoints_file(c).is_file()]
            if missing:
                raise UserError(f"the keypoint-guided MammaNet ({loaded.config.name}) reads keypoints, and "
                                f"{', '.join(missing)} have none (keypoints/<cam>.npz)",
                                "run `mamma-kit keypoints WORKSPACE` first (or pass --arch embedded for the "
                                "image-only model)")
            for c in cams:
                unit_inputs[c].append(ws.keypoints_file(c))
        from mamma_kit.landmarks.hands import hand_refiner

        from mamma_kit.landmarks.smooth import SMOOTH_S

        refiner = hand_refiner(loaded.landmark_set, hands)
        contact_loaded = contact_network(loaded, contact, device)
        if contact_loaded is not None:
            for c in cams:
                unit_inputs[c].append(Path(contact_loaded.source))
        settings = {"source": "net", "arch": loaded.config.name, "weights": loaded.source,
                    "hands": refiner.loaded.source if refiner else "off",
                    "contact": contact_loaded.source if contact_loaded else "own",
                    "smooth_s": float(SMOOTH_S if smooth_s is None else smooth_s)}
        if refiner:  # the hand network reads the keypoints too, where there are any
            for c in cams:
                unit_inputs[c].append(Path(refiner.loaded.source))
                if not loaded.config.keypoints_in and ws.keypoints_file(c).is_file():
                    unit_inputs[c].append(ws.keypoints_file(c))
    per_cam, todo = {}, []
    for cam in cams:
        manifest = StageManifest(ws.cache_dir, f"landmarks-{cam}", ws.root)
        state = manifest.check(unit_inputs[cam], {**settings, "camera": cam})
        if state.fresh and not force and ws.landmarks_file(cam).is_file():
            per_cam[cam] = {"camera": cam, "skipped": True, **manifest.load().get("summary", {})}
        else:
            todo.append(cam)
    from mamma_kit.core.executor import frame_ranges, run_units
    from mamma_kit.core.tracks import join_frame_ranges, track_frame_count
    _PREDICTORS.clear()  # a fresh model per call here, as before; workers keep theirs across units

    # units: (camera, frame range); one range per camera unless unit_frames (or MAMMA_KIT_UNIT_FRAMES)
    # splits it (network cameras only). A network unit computes on one thread (its convolutions' sums
    # would follow the thread count: core/reproducible.py), so the units run side by side, one process
    # per core; the cheap ground-truth units run here in order
    units = [(cam, r) for cam in todo for r in
             ([None] if source == "gt" else frame_ranges(track_frame_count(ws.mask_file(cam)),
                                                           unit_frames))]
    unit = partial(_landmarks_range, root=ws.root, source=source, settings=settings, unit_inputs=unit_inputs,
                   noise=noise, outliers=outliers, seed=seed, loaded=loaded, device=device, batch=batch,
                   refiner=refiner, contact=contact_loaded)
    parts: dict[str, list] = {cam: [] for cam in todo}
    for (cam, frames), (summ, lt) in zip(units, run_units(unit, units, threaded=source == "gt")):
        parts[cam].append((frames, lt, summ))
    for cam in todo:
        if len(parts[cam]) == 1:  # a whole camera: its unit wrote it (so a stopped run keeps it)
            per_cam[cam] = {"camera": cam, "skipped": False, **parts[cam][0][2]}
            continue
        lt = join_frame_ranges([(*fr, part) for fr, part, _ in parts[cam]])
        summs = [sm for *_, sm in parts[cam]]
        secs = sum(sm["seconds"] for sm in summs)
        summ = {"camera": cam, "crops": sum(sm["crops"] for sm in summs), "frames": sum(sm["frames"] for sm in summs),
                "tracks": summs[0]["tracks"], "seconds": round(secs, 3), "units": len(summs)}
        summ["crops_per_s"] = round(summ["crops"] / secs, 2) if secs > 0 else None
        per_cam[cam] = {"camera": cam, "skipped": False,
                        **_write_camera(ws, cam, lt, summ, settings, unit_inputs, secs)}
    ran = todo
    per_cam = [per_cam[c] for c in cams]
    secs = time.perf_counter() - t0
    if ran:
        log.info(f"landmarks written for {', '.join(ran)} in {secs:.1f} s")
    else:
        log.info("landmarks: up to date (inputs unchanged); skipped (--force recomputes)")
    summary = {"stage": "landmarks", "skipped": not ran, "reason": "inputs unchanged" if not ran else
               f"ran {', '.join(ran)}", "source": source, "cameras": per_cam, "seconds": round(secs, 2)}
    if loaded is not None:
        summary.update({"arch": loaded.config.name, "weights": loaded.source, "landmark_set": loaded.landmark_set})
    return summary


class LandmarksReader:
    """Landmarks of tracks that are not the workspace's masks file (those `mamma-kit fill` adds), with
    the network and settings the stage would use (``options``: capture.toml's [settings.landmarks]):
    the same crops, hand refinement, contact network and smoothing, so they read like the rest. The
    networks load once, for every camera read after."""

    def __init__(self, options: dict | None = None, device: str = "cpu"):
        from mamma_kit.landmarks.hands import hand_refiner
        from mamma_kit.landmarks.inference import Predictor
        from mamma_kit.landmarks.smooth import SMOOTH_S
        from mamma_kit.landmarks.weights import load_model

        self.opts = options or {}
        loaded = load_model(self.opts.get("weights"), self.opts.get("arch"), device)
        self.pred = Predictor(loaded, device)
        self.refiner = hand_refiner(loaded.landmark_set, self.opts.get("hands", "auto"))
        contact = contact_network(loaded, self.opts.get("contact", "auto"), device)
        self.contact = contact and Predictor(contact, device)
        self.smooth_s = float(SMOOTH_S if self.opts.get("smooth_s") is None else self.opts["smooth_s"])

    def __call__(self, ws, cam: str, masks, keypoints):
        from mamma_kit.core.reproducible import one_thread
        from mamma_kit.landmarks.inference import run_camera
        from mamma_kit.landmarks.smooth import smooth_landmarks

        entry = ws.load_capture().cameras[cam]
        with one_thread():
            lt, _ = run_camera(self.pred, cam, masks, entry.video, int(self.opts.get("batch", 8)),
                               keypoints=keypoints, hands=self.refiner, contact=self.contact,
                               rotation=entry.rotation)
        return smooth_landmarks(lt, self.smooth_s) if self.smooth_s > 0 else lt


_PREDICTORS: dict = {}
# the image-only single-query network: its person-contact head beats the keypoint-guided one's (demo,
# builtin masks, smoothed: ROC AUC 0.946 against 0.859; held-out duo, true masks: 0.968 against 0.823)
EMBEDDED_CONTACT = "embedded-single.pt"


def contact_network(loaded, contact: str | Path | None, device: str = "cpu"):
    """The network whose person-contact head the landmarks take (None: ``loaded``'s own): "auto" the
    shipped single-query network when ``loaded`` reads keypoints and it predicts the same landmark
    set; "off"; or a weights path (an image-only network of the same landmark set)."""
    from mamma_kit.landmarks.weights import EMBEDDED_DIR, load_model

    if contact in (None, "off", "own", False):
        return None
    auto = str(contact) == "auto"
    path = EMBEDDED_DIR / EMBEDDED_CONTACT if auto else Path(contact)
    if auto and (not loaded.config.keypoints_in or not path.is_file()):
        return None
    other = load_model(path, None, device)
    if other.config.keypoints_in or other.config.others_in_stem or other.landmark_set != loaded.landmark_set:
        if auto:
            return None
        raise UserError(f"contact network {path} is not an image-only network of landmark set "
                        f"'{loaded.landmark_set}'", "pass --contact off, or weights like embedded-single.pt")
    return other


def _landmarks_range(unit: tuple[str, tuple[int, int] | None], root: Path, source: str, settings: dict,
                     unit_inputs: dict, noise: str, outliers: float, seed: int, loaded, device: str, batch: int,
                     refiner=None, contact=None):
    """One (camera, frame range), here or in a worker: (summary, None) for a whole camera, whose
    landmarks/<cam>.npz and manifest it writes itself; else (summary, landmarks with rows
    start:stop filled) for run_landmarks to join."""
    from mamma_kit.core.workspace import Workspace

    cam, frames = unit
    ws = Workspace(root)
    t0 = time.perf_counter()
    if source == "gt":
        from mamma_kit.landmarks.gt import noisy_gt_landmarks

        lt, summ = noisy_gt_landmarks(ws, cam, noise, outliers, seed)
        return _write_camera(ws, cam, lt, summ, settings, unit_inputs, time.perf_counter() - t0), None
    from mamma_kit.core.reproducible import one_thread
    from mamma_kit.core.tracks import KeypointTracks, MaskTracks
    from mamma_kit.landmarks.inference import Predictor, run_camera

    key = (id(loaded), id(contact), device)  # one predictor per model and process, as the cameras' loop had
    if key not in _PREDICTORS:
        _PREDICTORS.clear()
        _PREDICTORS[key] = (loaded, Predictor(loaded, device), contact and Predictor(contact, device))
    _, pred, pred_contact = _PREDICTORS[key]
    cap = ws.load_capture()
    masks = MaskTracks.load(ws.mask_file(cam))
    use_kp = loaded.config.keypoints_in or (refiner is not None and ws.keypoints_file(cam).is_file())
    kt = KeypointTracks.load(ws.keypoints_file(cam)) if use_kp else None
    whole = frames == (0, len(masks.frame_times))
    with one_thread():  # the same bits whatever the cores, the executor or the other units
        lt, summ = run_camera(pred, cam, masks, cap.cameras[cam].video, batch, keypoints=kt,
                              frame_range=None if whole else frames, hands=refiner, contact=pred_contact,
                              rotation=cap.cameras[cam].rotation)
    if whole:
        return _write_camera(ws, cam, lt, summ, settings, unit_inputs, time.perf_counter() - t0), None
    return summ, lt


def _write_camera(ws, cam: str, lt, summ: dict, settings: dict, unit_inputs: dict, seconds: float) -> dict:
    """landmarks/<cam>.npz and its manifest, from the camera's landmarks (``seconds``: computing them);
    the network's contact and visibility smoothed first (the whole camera's tracks: here, after any
    frame ranges are joined)."""
    if settings.get("smooth_s", 0) > 0:
        from mamma_kit.landmarks.smooth import smooth_landmarks

        lt = smooth_landmarks(lt, settings["smooth_s"])
    manifest = StageManifest(ws.cache_dir, f"landmarks-{cam}", ws.root)
    inputs, out = unit_inputs[cam], ws.landmarks_file(cam)
    tc = time.perf_counter()
    hashes = {ws.relative(p): manifest.hasher(p) for p in inputs}
    lt.producer = producer("landmarks " + " ".join(f"{k}={v}" for k, v in settings.items()), hashes)
    lt.save(out)
    manifest.record(inputs, {**settings, "camera": cam}, [out], summ, seconds + time.perf_counter() - tc)
    return summ
