"""What the report reads from a workspace, loaded once and only if present.

``ReportData(ws)`` exposes the workspace's files as objects (None when a file is absent):
rig and calibration diagnostics, clock models, landmark and keypoint tracks (core.filled.CameraTracks:
read a window of frames at a time, so a take of minutes is never held), identities, fitted people,
the fit report; plus the body posed at arbitrary reference times, interpolated linearly between the
two fitted frames around each time.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from mamma_kit.core.clock import ClockModel
from mamma_kit.core.workspace import Workspace

#: Landmarks count as observed when their visibility exceeds this (as in the fit's report).
MIN_VIS = 0.5
#: Frames of a camera read (and bodies posed) at once when a figure goes over the take.
BLOCK = 256


@dataclass
class Person:
    id: int
    result: object  # core.smplxfile.SmplxResult

    @property
    def frame_times(self) -> np.ndarray:
        return self.result.frame_times


class ReportData:
    """Lazily loaded inputs of the report (see module doc)."""

    def __init__(self, ws: Workspace):
        self.ws = ws
        self.notes: list[str] = []

    # ---- files ---------------------------------------------------------------------------
    @cached_property
    def capture(self):
        return self.ws.load_capture() if self.ws.capture_toml.is_file() else None

    @cached_property
    def name(self) -> str:
        return self.capture.name if self.capture else self.ws.root.name

    @cached_property
    def calibration(self):
        """(Rig, diagnostics) or None."""
        if not self.ws.calibration.is_file():
            return None
        from mamma_kit.core.calibfile import read_calibration

        return read_calibration(self.ws.calibration)

    @property
    def rig(self):
        return self.calibration[0] if self.calibration else None

    @cached_property
    def timing(self):
        """(clocks, info) or None."""
        if not self.ws.timing.is_file():
            return None
        from mamma_kit.core.timingfile import read_timing

        return read_timing(self.ws.timing)

    def clock(self, cam: str) -> ClockModel:
        """The camera's clock model; identity when timing.toml is absent or lacks it."""
        if self.timing and cam in self.timing[0]:
            return self.timing[0][cam]
        return ClockModel()

    @cached_property
    def cameras(self) -> list[str]:
        """Cameras in capture.toml order (else calibration order, else landmark files)."""
        if self.capture:
            return self.capture.camera_names
        if self.rig:
            return self.rig.names
        return sorted(p.stem for p in self.ws.landmarks_dir.glob("*.npz"))

    @cached_property
    def landmarks(self) -> dict:
        """camera -> its landmark tracks (core.filled.CameraTracks, with the fill's) for every camera
        with landmarks/<cam>.npz."""
        from mamma_kit.core.filled import open_tracks

        return {c: open_tracks(self.ws, "landmarks", c) for c in self.cameras
                if self.ws.landmarks_file(c).is_file()}

    @cached_property
    def keypoints(self) -> dict:
        """camera -> its keypoint tracks (core.filled.CameraTracks, with the fill's) for every camera
        with keypoints/<cam>.npz."""
        from mamma_kit.core.filled import open_tracks

        return {c: open_tracks(self.ws, "keypoints", c) for c in self.cameras
                if self.ws.keypoints_file(c).is_file()}

    @cached_property
    def mask_tracks(self) -> dict:
        from mamma_kit.core.filled import load_masks

        return {c: load_masks(self.ws, c, placed=True) for c in self.cameras if self.ws.mask_file(c).is_file()}

    @cached_property
    def identities(self):
        if not self.ws.identities.is_file():
            return None
        from mamma_kit.core.filled import load_identities

        return load_identities(self.ws, placed=True)

    def person_of_track(self, cam: str) -> dict[int, int]:
        """track id -> person id in one view (identities.json, else track id = person id)."""
        lt = self.landmarks.get(cam)
        if self.identities is not None:
            return {int(t): int(p) for t, p in self.identities.assignments.get(cam, {}).items()}
        return {} if lt is None else {int(t): int(t) for t in lt.track_ids}

    def track_columns(self, cam: str, pid: int) -> np.ndarray:
        """Columns of landmarks[cam] whose track shows person ``pid``."""
        lt = self.landmarks[cam]
        pmap = self.person_of_track(cam)
        return np.flatnonzero([pmap.get(int(t)) == pid for t in lt.track_ids])

    @cached_property
    def people(self) -> list[Person]:
        from mamma_kit.core.smplxfile import read_smplx_result

        return [Person(int(p.stem.split("_")[1]), read_smplx_result(p)) for p in self.ws.person_files()]

    @cached_property
    def fit_report(self) -> dict | None:
        from mamma_kit.core.io import read_json

        p = self.ws.smplx_dir / "fit_report.json"
        return read_json(p, "fit_report.json") if p.is_file() else None

    @cached_property
    def body_model(self):
        """The body model the people were fitted with (capture.toml's, else the open body)."""
        from mamma_kit.body.model import load_body_model

        spec = self.capture.body_model if self.capture else "open"
        model = load_body_model(spec)
        fitted = {p.result.body_model_sha256 for p in self.people}
        if fitted and model.sha256 not in fitted:
            self.notes.append(f"the people were fitted with another body model than capture.toml's '{spec}'")
        return model

    def video(self, cam: str):
        """The camera's capture video path, or None when capture.toml lacks it or it is absent."""
        if not self.capture or cam not in self.capture.cameras:
            return None
        p = self.capture.cameras[cam].video
        return p if p.is_file() else None

    def rotation(self, cam: str) -> int | None:
        """capture.toml's override of the camera's display rotation (None: the file's own)."""
        return self.capture.cameras[cam].rotation if self.capture and cam in self.capture.cameras else None

    # ---- the body at given times ---------------------------------------------------------
    @staticmethod
    def interpolation(frame_times: np.ndarray, t_ref: np.ndarray):
        """Frames (i0, i1) and weight a of t_ref between fitted frames, and whether t_ref lies
        inside the fitted span (half a frame of slack at the ends)."""
        ft = np.asarray(frame_times, float)
        t = np.asarray(t_ref, float)
        if len(ft) == 1:
            z = np.zeros(len(t), int)
            return z, z, np.zeros(len(t)), np.abs(t - ft[0]) < 0.02
        half = 0.5 * float(np.median(np.diff(ft)))
        i0 = np.clip(np.searchsorted(ft, t, side="right") - 1, 0, len(ft) - 2)
        i1 = i0 + 1
        a = np.clip((t - ft[i0]) / (ft[i1] - ft[i0]), 0.0, 1.0)
        inside = (t >= ft[0] - half) & (t <= ft[-1] + half)
        return i0, i1, a, inside

    def landmarks_at(self, person: Person, t_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Landmark vertices (N, L, 3) at reference times (N,), and (N,) inside the fitted span.
        Only the fitted frames around the asked times are posed."""
        import torch

        from mamma_kit.body.lbs import pose_restricted

        i0, i1, a, inside = self.interpolation(person.frame_times, t_ref)
        need, inv = np.unique(np.r_[i0, i1], return_inverse=True)
        X_nl3 = np.empty((len(need), len(self.body_model.landmark_ids), 3), np.float32)
        with torch.no_grad():
            for s in range(0, len(need), BLOCK):
                prm = person.result.params(need[s:s + BLOCK])
                v, _ = pose_restricted(self.body_model, {k: torch.as_tensor(np.asarray(x), dtype=torch.float32)
                                                         for k, x in prm.items()})
                X_nl3[s:s + BLOCK] = v.numpy()
        j0, j1 = inv[:len(i0)], inv[len(i0):]
        w = a[:, None, None].astype(np.float32)
        return (1 - w) * X_nl3[j0] + w * X_nl3[j1], inside

    def meshes_at(self, person: Person, t_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full posed meshes (N, V, 3) at reference times (N,), and (N,) inside the fitted span.
        Only the fitted frames around the asked times are posed."""
        from mamma_kit.body.lbs import pose_mesh_np

        i0, i1, a, inside = self.interpolation(person.frame_times, t_ref)
        need, inv = np.unique(np.r_[i0, i1], return_inverse=True)
        V_nv3, _ = pose_mesh_np(self.body_model, person.result.params(need))
        j0, j1 = inv[:len(i0)], inv[len(i0):]
        w = a[:, None, None].astype(np.float32)
        return (1 - w) * V_nv3[j0] + w * V_nv3[j1], inside
