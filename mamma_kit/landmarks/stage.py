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

import numpy as np

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
    from mamma_kit.core.tracks import track_frame_count
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
    for (cam, frames), summ in zip(units, run_units(unit, units, threaded=source == "gt")):
        parts[cam].append((frames, summ))
    for cam in todo:
        if len(parts[cam]) == 1:  # a whole camera: its unit wrote it (so a stopped run keeps it)
            per_cam[cam] = {"camera": cam, "skipped": False, **parts[cam][0][1]}
            continue
        summs = [sm for _, sm in parts[cam]]
        secs = sum(sm["seconds"] for sm in summs)
        summ = {"camera": cam, "crops": sum(sm["crops"] for sm in summs), "frames": sum(sm["frames"] for sm in summs),
                "tracks": summs[0]["tracks"], "seconds": round(secs, 3), "units": len(summs)}
        summ["crops_per_s"] = round(summ["crops"] / secs, 2) if secs > 0 else None
        per_cam[cam] = {"camera": cam, "skipped": False,
                        **_join_parts(ws, cam, [fr for fr, _ in parts[cam]], summ, settings, unit_inputs, secs)}
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
    the same crops, hand refinement, contact network and smoothing, so they read like the rest
    (``write``). The networks load once, for every camera read after."""

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

    def write(self, ws, cam: str, masks, keypoints_path: Path, path: Path) -> Path:
        """The landmarks of ``masks``' tracks (their keypoints in ``keypoints_path``) streamed into
        ``path``, smoothed as the stage smooths them."""
        from mamma_kit.core.reproducible import one_thread
        from mamma_kit.core.trackrows import TrackFile
        from mamma_kit.core.tracks import KeypointTracks
        from mamma_kit.landmarks.inference import run_camera

        entry = ws.load_capture().cameras[cam]
        header = {"camera": cam, "image_size": masks.image_size, "frame_times": masks.frame_times,
                  "track_ids": masks.track_ids, "landmark_set": self.pred.loaded.landmark_set,
                  "source": f"mammanet:{self.pred.cfg.name}", "producer": {}}
        with TrackFile(keypoints_path, KeypointTracks, "keypoint file") as kf, \
                FileSink(path, header, self.pred.n_landmarks, self.smooth_s) as sink:
            with one_thread():
                run_camera(self.pred, cam, masks, entry.video, int(self.opts.get("batch", 8)), keypoints=kf,
                           hands=self.refiner, contact=self.contact, rotation=entry.rotation, sink=sink)
            return sink.close()


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
                     refiner=None, contact=None) -> dict:
    """One (camera, frame range), here or in a worker; returns its summary. A whole camera writes
    landmarks/<cam>.npz and its manifest itself, streaming its rows into the file; a part of a
    camera writes its rows, not yet smoothed, into a part file that run_landmarks joins."""
    from mamma_kit.core.workspace import Workspace

    cam, frames = unit
    ws = Workspace(root)
    t0 = time.perf_counter()
    if source == "gt":
        from mamma_kit.landmarks.gt import noisy_gt_landmarks

        lt, summ = noisy_gt_landmarks(ws, cam, noise, outliers, seed)
        o = _Output(ws, cam, settings, unit_inputs)
        lt.producer = o.producer()
        lt.save(o.path)
        return o.record(summ, time.perf_counter() - t0)
    from mamma_kit.core.reproducible import one_thread
    from mamma_kit.core.trackrows import TrackFile
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
    kt = TrackFile(ws.keypoints_file(cam), KeypointTracks, "keypoint file") if use_kp else None
    whole = frames == (0, len(masks.frame_times))
    header = {"camera": cam, "image_size": masks.image_size, "frame_times": masks.frame_times,
              "track_ids": masks.track_ids, "landmark_set": loaded.landmark_set,
              "source": f"mammanet:{pred.cfg.name}", "producer": {}}
    o = _Output(ws, cam, settings, unit_inputs)
    path = o.path if whole else part_file(ws, cam, frames)
    with FileSink(path, header, pred.n_landmarks, settings.get("smooth_s", 0) if whole else 0) as sink:
        with one_thread():  # the same bits whatever the cores, the executor or the other units
            _, summ = run_camera(pred, cam, masks, cap.cameras[cam].video, batch, keypoints=kt,
                                 frame_range=None if whole else frames, hands=refiner, contact=pred_contact,
                                 rotation=cap.cameras[cam].rotation, sink=sink)
        if kt is not None:
            kt.close()
        if not whole:
            sink.close()
            return summ
        sink.writer.header["producer"] = o.producer()
        sink.close()
        return o.record(summ, time.perf_counter() - t0)


def part_file(ws, cam: str, frames: tuple[int, int]) -> Path:
    """Where a unit of a split camera leaves its rows for the join (beside the camera's file)."""
    return ws.landmarks_dir / f".{cam}.{frames[0]}-{frames[1]}.part.npz"


class FileSink:
    """run_camera's rows streamed into a landmark file (core.trackrows.RowWriter), the network's
    contact and visibility smoothed on the way (landmarks/smooth.RowSmoother) unless smooth_s is 0."""

    def __init__(self, path: Path, header: dict, n_landmarks: int, smooth_s: float = 0.0):
        from mamma_kit.core.trackrows import RowWriter
        from mamma_kit.core.tracks import LandmarkTracks
        from mamma_kit.landmarks.smooth import RowSmoother, contact_neighbours

        self.writer = RowWriter(path, LandmarkTracks, header, n_landmarks)
        self.smoother = RowSmoother(header["frame_times"], smooth_s, contact_neighbours(
            header["landmark_set"], n_landmarks)) if smooth_s and smooth_s > 0 else None

    def add(self, t_n, k_n, cells: dict, complete_before: int) -> None:
        cells = {**cells, "valid": np.ones(len(t_n), bool)}
        if self.smoother is not None:
            t_n, k_n, cells = self.smoother.push(t_n, k_n, cells, complete_before)
        self.writer.append(t_n, k_n, **cells)

    def finish(self) -> None:
        if self.smoother is not None:
            t_n, k_n, cells = self.smoother.finish()
            self.writer.append(t_n, k_n, **cells)
            self.smoother = None

    def close(self) -> Path:
        self.finish()
        return self.writer.close()

    def __enter__(self) -> "FileSink":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is not None:
            self.writer.abort()


class _Output:
    """A camera's landmark file and manifest: the producer record to put in the file and the
    manifest written once the file is (``record``)."""

    def __init__(self, ws, cam: str, settings: dict, unit_inputs: dict):
        self.ws, self.cam, self.settings, self.inputs = ws, cam, settings, unit_inputs[cam]
        self.path = ws.landmarks_file(cam)
        self.manifest = StageManifest(ws.cache_dir, f"landmarks-{cam}", ws.root)

    def producer(self) -> dict:
        hashes = {self.ws.relative(p): self.manifest.hasher(p) for p in self.inputs}
        return producer("landmarks " + " ".join(f"{k}={v}" for k, v in self.settings.items()), hashes)

    def record(self, summ: dict, seconds: float) -> dict:
        self.manifest.record(self.inputs, {**self.settings, "camera": self.cam}, [self.ws.landmarks_file(self.cam)],
                             summ, seconds)
        return summ


def _join_parts(ws, cam: str, ranges: list, summ: dict, settings: dict, unit_inputs: dict, seconds: float) -> dict:
    """landmarks/<cam>.npz from the part files of a split camera: their rows in frame order, smoothed
    as a whole camera's are (the smoothing reaches across the parts' edges), then the manifest."""
    from mamma_kit.core.trackrows import TrackFile
    from mamma_kit.core.tracks import LandmarkTracks

    tc = time.perf_counter()
    paths = [part_file(ws, cam, fr) for fr in ranges]
    with TrackFile(paths[0], LandmarkTracks, "landmark file") as first:
        header = {**first.header}
        n = first.n
    o = _Output(ws, cam, settings, unit_inputs)
    with FileSink(o.path, header, n, settings.get("smooth_s", 0)) as sink:
        for (a, b), p in zip(ranges, paths):
            with TrackFile(p, LandmarkTracks, "landmark file") as part:
                for s in range(a, b, 256):
                    t_n, k_n, d = part.rows(s, min(b, s + 256))
                    d.pop("valid", None)
                    sink.add(t_n, k_n, d, complete_before=min(b, s + 256))
        sink.writer.header["producer"] = o.producer()
        sink.close()
        for p in paths:
            p.unlink(missing_ok=True)
        return o.record(summ, seconds + time.perf_counter() - tc)
