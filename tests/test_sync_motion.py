"""Motion sync on keypoints with known clocks: two people moving in front of a calibrated ring of
cameras, each camera's frames taken at its own offset (sub-frame), projected to BlazePose-shaped
keypoint tracks; the solver must return the offsets."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_ring_rig

from mamma_kit.core.tracks import KeypointTracks
from mamma_kit.timing.motion import motion_clocks


def moving_people(t: np.ndarray, rng) -> np.ndarray:
    """(P=2, T, 33, 3) joints of two people swinging their limbs (smooth, non-periodic motion)."""
    base = rng.uniform(-0.3, 0.3, (33, 3)) + np.array([0, 0, 1.0])
    out = []
    for p, x0 in enumerate((-0.6, 0.6)):
        freq = rng.uniform(0.6, 2.2, (33, 3))
        phase = rng.uniform(0, 2 * np.pi, (33, 3))
        amp = rng.uniform(0.05, 0.25, (33, 3))
        J = base + np.array([x0, 0.2 * p, 0]) + amp * np.sin(2 * np.pi * freq * t[:, None, None] + phase)
        sway = np.stack([0.3 * np.sin(0.7 * t + p), 0 * t, 0 * t], -1)[:, None, :]  # (T, 1, 3)
        out.append(J + sway)
    return np.stack(out)


def tracks(rig, offsets: dict[str, float], fps: float = 30.0, seconds: float = 6.0, noise_px: float = 0.5, seed=0):
    rng = np.random.default_rng(seed)
    kts = {}
    for cam in rig:
        t_cam = np.arange(0, seconds, 1 / fps) + rng.normal(0, 0.0005, int(seconds * fps))  # VFR jitter
        t_cam.sort()
        J = moving_people(t_cam + offsets[cam.name], np.random.default_rng(123))  # the same people for all
        xy = np.stack([cam.project(J[p]) for p in range(2)], 1)  # (T, 2, 33, 2)
        xy += np.random.default_rng(seed + 1).normal(0, noise_px, xy.shape)
        kt = KeypointTracks.empty(cam.name, cam.size, t_cam, np.arange(2))
        kt.valid[:] = True
        kt.xy[:] = xy
        kt.visibility[:] = 1.0
        order = rng.permutation(2)  # track ids differ between views
        kt.xy = kt.xy[:, order]
        kts[cam.name] = kt
    return kts


def test_motion_sync_recovers_sub_frame_offsets():
    rig = make_ring_rig(4, size=(960, 540), f=800.0)
    truth = {"cam0": 0.0, "cam1": 0.0123, "cam2": -0.0571, "cam3": 0.2038}
    clocks, diag, _ = motion_clocks(tracks(rig, truth), rig, "cam0")
    for n, o in truth.items():
        assert clocks[n].offset == pytest.approx(o, abs=0.002), n  # within 2 ms (a 30 fps frame is 33 ms)


def test_motion_sync_without_motion_says_so():
    from mamma_kit.core.errors import UserError

    rig = make_ring_rig(3, size=(960, 540), f=800.0)
    kts = tracks(rig, {c.name: 0.0 for c in rig})
    for kt in kts.values():
        kt.xy[:] = kt.xy[:1]
    with pytest.raises(UserError, match="too little shared motion"):
        motion_clocks(kts, rig, "cam0")


def test_motion_sync_finds_drift_over_a_long_take_with_gaps():
    """A minute recorded in three bursts (the timestamps jump between them): the offset and drift of
    each camera from the windows, never interpolating across a gap."""
    rig = make_ring_rig(3, size=(960, 540), f=800.0)
    truth = {"cam0": (0.0, 0.0), "cam1": (0.0123, 30e-6), "cam2": (-0.0571, -20e-6)}  # t_ref = (1 + r) t + o
    rng = np.random.default_rng(0)
    kts = {}
    for cam in rig:
        o, r = truth[cam.name]
        t = np.sort(np.arange(0, 60, 1 / 15) + rng.normal(0, 0.0005, 900))
        t = t[(t < 4) | ((t > 28) & (t < 32)) | (t > 56)]
        J = moving_people((1 + r) * t + o, np.random.default_rng(123))
        kt = KeypointTracks.empty(cam.name, cam.size, t, np.arange(2))
        kt.valid[:] = True
        kt.xy[:] = np.stack([cam.project(J[p]) for p in range(2)], 1) + rng.normal(0, 0.5, (len(t), 2, 33, 2))
        kt.visibility[:] = 1.0
        kts[cam.name] = kt
    clocks, diag, notes = motion_clocks(kts, rig, "cam0")
    assert not notes
    for n, (o, r) in truth.items():
        assert clocks[n].offset == pytest.approx(o, abs=0.002), n
        assert clocks[n].rate == pytest.approx(r, abs=10e-6), n  # the issue asks 10 ppm over 2 minutes
    assert diag["cam1"]["pairs"]["cam0-cam1"]["drift"]["windows_s"] == pytest.approx([2.0, 30.0, 58.0], abs=0.1)


def test_joint_refinement_pulls_every_camera_to_the_truth_from_a_third_of_a_frame_off():
    """refine_jointly solves all offsets at once from all pairs' signed distances: started 9-12 ms
    (a third of a 30 fps frame) off, it ends within 0.2 ms; its standard deviations are small and
    positive, and motion_clocks reports what the refinement moved."""
    from mamma_kit.timing import motion as M

    rig = make_ring_rig(4, size=(960, 540), f=800.0)
    truth = {"cam0": 0.0, "cam1": 0.0123, "cam2": -0.0571, "cam3": 0.2038}
    kts = tracks(rig, truth)
    names = list(truth)
    views = {n: M.View.of(rig[n], kts[n]) for n in names}
    true = np.array([truth[n] for n in names])
    track_pairs = {(a, b): M.pair_tracks(views[a], views[b], views[a].cam.fundamental_to(views[b].cam),
                                         truth[b] - truth[a]) for i, a in enumerate(names) for b in names[i + 1:]}
    off, sd = M.refine_jointly(views, names, "cam0", true + np.array([0.0, 0.011, -0.009, 0.012]), track_pairs)
    assert np.abs(off - true).max() < 2e-4
    assert sd[0] == 0 and (sd[1:] > 0).all() and (sd[1:] < 1e-3).all()
    _, diag, _ = motion_clocks(kts, rig, "cam0")
    assert {"pairs_solve_ms", "joint_refinement_ms", "offset_sd_independent_errors_ms"} <= set(diag["cam1"])
