"""The fit's physical self-checks: a plausible take passes; each injected impossibility is flagged
by its own check, at the frames it happened in, with a cause."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_ring_rig

from mamma_kit.fitting.checks import IMPOSSIBLE, check_fit, runs, summary_lines

FPS = 30.0
T = 60


def _take(rig, P: int = 2, seed: int = 0):
    """Two people walking 1.2 m/s side by side, 1.7 m tall, feet on the floor; every camera sees both."""
    rng = np.random.default_rng(seed)
    body = np.c_[rng.normal(0, 0.12, (55, 2)), np.linspace(0.05, 1.7, 55)]
    body[0] = [0.0, 0.0, 0.95]  # the pelvis
    joints = np.zeros((P, T, 55, 3))
    for p in range(P):
        start = np.array([-0.6 + 1.0 * p, -0.5, 0.0])
        for t in range(T):
            joints[p, t] = body + start + np.array([0.0, 1.2 * t / FPS, 0.0])
    times = 5.0 + np.arange(T) / FPS
    seen = np.ones((len(rig), P, T), bool)
    return joints, np.ones((P, T), bool), seen, times


def _check(rig, joints, observed, seen, times, heights=(1.7, 1.7), floor=True):
    return check_fit(joints, observed, seen, times, rig, floor, np.array(heights), [0, 4])


@pytest.fixture(scope="module")
def rig():
    return make_ring_rig(4, radius=4.0, height=1.6)


def test_a_plausible_take_passes_every_check(rig):
    c = _check(rig, *_take(rig))
    assert c["passed"] and c["flags"] == [] and c["impossible_frames"] == 0 and c["doubtful_frames"] == 0


def _only(c, check, person, frames):
    got = {(f["check"], f["person"]) for f in c["flags"]}
    assert got == {(check, person)}, c["flags"]
    f = c["flags"][0]
    assert f["frames"] == list(frames) and f["cause"] and f["what"], f
    assert c["passed"] == (check not in IMPOSSIBLE)


def test_a_body_at_a_camera_is_flagged_inside_it(rig):
    joints, obs, seen, times = _take(rig)
    centre = rig.centers()[2]
    joints[1, 20:31] += (centre - joints[1, 20:31, 0])[:, None]  # person 4's pelvis onto cam2's centre
    seen[:, 1, 20:31] = False
    seen[[0, 1], 1, 20:31] = True  # seen by cam0 and cam1 only (they look at it from afar)
    c = _check(rig, joints, obs, seen, times)
    assert {f["check"] for f in c["flags"] if f["person"] == 4} >= {"inside_camera"}
    inside = [f for f in c["flags"] if f["check"] == "inside_camera"][0]
    assert inside["frames"] == [20, 30] and "cam2" in inside["what"] and not c["passed"]


def test_a_body_behind_a_camera_that_sees_it_is_flagged(rig):
    joints, obs, seen, times = _take(rig)
    cam = rig[0]
    behind = cam.center - 1.5 * cam.R[2]  # 1.5 m behind cam0, along its optical axis
    joints[0, 40:50] += (behind - joints[0, 40:50, 0])[:, None]
    c = _check(rig, joints, obs, seen, times)
    f = [f for f in c["flags"] if f["check"] == "behind_camera" and "cam0" in f["what"]]
    assert f and f[0]["person"] == 0 and f[0]["frames"] == [40, 49] and not c["passed"]


def test_a_body_under_the_floor_is_flagged_only_where_the_floor_is_known(rig):
    joints, obs, seen, times = _take(rig)
    joints[1, :, :, 2] -= 0.5  # the whole take (a sudden drop would also be too fast)
    _only(_check(rig, joints, obs, seen, times), "below_floor", 4, (0, T - 1))
    assert _check(rig, joints, obs, seen, times, floor=False)["passed"]


def test_a_jump_across_the_room_between_frames_is_too_fast(rig):
    joints, obs, seen, times = _take(rig)
    joints[0, 30:] += np.array([1.5, 0.0, 0.0])  # 1.5 m in 1/30 s: 45 m/s
    c = _check(rig, joints, obs, seen, times)
    fast = [f for f in c["flags"] if f["check"] == "too_fast"]
    assert len(fast) == 1 and fast[0]["person"] == 0 and fast[0]["frames"] == [30, 30] and "45" in fast[0]["what"]
    assert "identities.json" in fast[0]["cause"] and not c["passed"]


def test_two_persons_in_one_place_are_flagged(rig):
    joints, obs, seen, times = _take(rig)
    joints[1] = joints[0] + 0.05  # person 4 fitted onto person 0 for the whole take
    _only(_check(rig, joints, obs, seen, times), "same_place", 0, (0, T - 1))


def test_doubtful_cases_are_flagged_without_failing(rig):
    joints, obs, seen, times = _take(rig)
    joints[0, :, :, 2] += 0.9  # standing 0.9 m up for the whole take: floating, not impossible
    c = _check(rig, joints, obs, seen, times, heights=(1.7, 2.6))
    assert c["passed"]
    assert {(f["check"], f["person"]) for f in c["flags"]} == {("floating", 0), ("height", 4)}
    # a camera that looks at a person for the whole take and never tracks them
    joints, obs, seen, times = _take(rig)
    seen[3, 1] = False
    c = _check(rig, joints, obs, seen, times)
    assert {(f["check"], f["person"]) for f in c["flags"]} == {("unseen", 4)} and "cam3" in c["flags"][0]["what"]


def test_two_nearly_parallel_views_leave_depth_doubtful(rig):
    joints, obs, _, times = _take(rig)
    far = make_ring_rig(8, radius=4.0)  # cam0 and cam1 of eight on a ring: about 45 degrees apart
    seen8 = np.zeros((8, 2, T), bool)
    seen8[[0, 1], 0] = True
    seen8[[0, 1], 1] = True
    c = _check(far, joints, obs, seen8, times)
    assert not [f for f in c["flags"] if f["check"] == "depth"]
    # two cameras side by side (0.2 m apart) looking at the person: rays ~3 degrees apart
    from mamma_kit.core.camera import Rig

    a = far[0]
    b = a.copy(name="cam_b", t=a.t + a.R @ np.array([-0.2, 0.0, 0.0]))
    pair = Rig([a, b])
    seen2 = np.ones((2, 2, T), bool)
    c = _check(pair, joints, obs, seen2, times)
    assert {f["check"] for f in c["flags"]} >= {"depth"} and c["passed"]


def test_runs_and_summary_lines():
    assert runs(np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)) == [(1, 2), (4, 4), (7, 7)]
    assert runs(np.zeros(3, bool)) == []
    c = {"flags": [{"person": 2, "check": "too_fast", "severity": "impossible", "frames": [3, 3], "times_s": [1.0, 1.0],
                    "what": "pelvis at 40.0 m/s", "cause": "a track switches person"}]}
    assert summary_lines(c) == ["person 2, frames 3-3 (1.00-1.00 s): too fast: pelvis at 40.0 m/s: a track switches person"]


# ---- each view against the fitted bodies (fitting/viewcheck.py) -----------------------------------

def _views_take(rig, P: int = 2, T_: int = 40, fps: float = 20.0, seed: int = 1):
    """Bodies of 48 points walking a curve at about 1.3 m/s, and every camera's view of them (0.5 px noise)."""
    rng = np.random.default_rng(seed)
    shape = np.c_[rng.normal(0, 0.15, (48, 2)), rng.uniform(0.0, 1.75, 48)]
    t = np.arange(T_) / fps
    world = np.zeros((P, T_, 48, 3))
    for p in range(P):
        path = np.c_[np.cos(1.0 * t + p * 2.5), np.sin(1.0 * t + p * 2.5), np.zeros(T_)] * 1.3
        world[p] = path[:, None] + shape[None] + rng.normal(0, 0.02, (1, 48, 3)) * p
    obs = np.stack([_view(rig[n], world, rng) for n in rig.names])
    return world, obs, fps


def _view(cam, world, rng):
    uv = cam.project(world.reshape(-1, 3)).reshape(*world.shape[:-1], 2)
    return uv + rng.normal(0, 0.5, uv.shape)


def _findings(rig, world, obs, fps):
    from mamma_kit.fitting.viewcheck import view_findings

    return view_findings(rig, world, obs, [0, 4])


def test_views_that_agree_with_the_bodies_give_no_finding(rig):
    assert _findings(rig, *_views_take(rig)) == []


def test_a_view_with_two_persons_swapped_is_named_with_the_swap(rig):
    world, obs, fps = _views_take(rig)
    obs[3, :, 10:30] = obs[3, ::-1, 10:30]  # cam3's tracks of the two persons exchanged in frames 10-29
    got = _findings(rig, world, obs, fps)
    assert {(f.check, f.person) for f in got} == {("view_swapped", 0), ("view_swapped", 1)}
    for f in got:
        assert list(np.flatnonzero(f.frames_t)) == list(range(10, 30)) and "cam3" in f.cause and "swapped" in f.cause


def _clock_findings(rig, world, fps, late_frames: int = 0):
    """clock_findings on every camera's BlazePose points of the bodies (their first 33 points, 0.5 px
    noise), cam3 showing at t what the bodies do ``late_frames`` later."""
    from mamma_kit.fitting.viewcheck import clock_findings

    rng = np.random.default_rng(7)
    kp = np.stack([_view(rig[n], world[:, :, :33], rng) for n in rig.names])  # (C, P, T, 33, 2)
    kp[3] = _view(rig["cam3"], np.roll(world[:, :, :33], -late_frames, axis=1), rng)
    times = 5.0 + np.arange(world.shape[1]) / fps
    return clock_findings(rig, times, kp, np.ones(kp.shape[:-1]), [0, 4])


def test_a_view_with_its_clock_off_is_named_with_the_offset(rig):
    world, _, fps = _views_take(rig)
    assert _clock_findings(rig, world, fps) == []
    got = _clock_findings(rig, world, fps, late_frames=6)  # 0.3 s
    assert {(f.check, f.person) for f in got} == {("view_clock", 0), ("view_clock", 1)}, [f.what for f in got]
    assert all("cam3" in f.cause and "0.30 s" in f.cause and "0.30 s later" in f.what for f in got), [f.what for f in got]


def test_a_view_whose_camera_moved_is_named_with_its_pose(rig):
    world, obs, fps = _views_take(rig)
    moved = rig["cam3"].copy()
    moved.t = moved.t - moved.R @ np.array([0.5, 0.0, 0.0])  # its centre 0.5 m along x from the calibration's
    obs[3] = _view(moved, world, np.random.default_rng(6))
    got = _findings(rig, world, obs, fps)
    assert {f.check for f in got} == {"view_pose"}, [(f.check, f.what) for f in got]
    assert all("cam3" in f.cause and "calibration.toml" in f.cause for f in got)


def test_view_findings_become_doubtful_flags(rig):
    world, obs, fps = _views_take(rig)
    obs[3, :, 10:30] = obs[3, ::-1, 10:30]
    joints, observed, seen, times = _take(rig)
    c = check_fit(joints, observed, seen, times, rig, True, np.array([1.7, 1.7]), [0, 4],
                  views=_findings(rig, world, obs, fps))
    assert c["passed"] and c["by_check"] == {"view_swapped": 40} and c["doubtful_frames"] == 40
    assert {f["person"] for f in c["flags"]} == {0, 4} and all(f["frames"] == [10, 29] for f in c["flags"])
