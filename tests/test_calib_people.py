"""Camera poses refined from the people (calibration/people.py, `calibrate --people`): a camera whose
calibrated pose is 4 deg and 8 cm off stands out and comes back to where its views of the people
put it, the others held; a right calibration stays where it is and no camera stands out; a
workspace without keypoints or a match is one clear line."""

from __future__ import annotations

import numpy as np
from conftest import make_ring_rig

from mamma_kit.calibration.people import Observations, cameras_off, refine_poses
from mamma_kit.core.camera import Rig, rotvec


def _people(T: int = 30, seed: int = 0) -> np.ndarray:
    """Two people's 23 body points walking past each other: (2, T, 23, 3)."""
    rng = np.random.default_rng(seed)
    body = np.c_[rng.normal(0, 0.15, (23, 2)), rng.uniform(0.05, 1.75, 23)]
    s = np.linspace(-1.0, 1.0, T)
    paths = [np.c_[s, np.full(T, -0.4), np.zeros(T)], np.c_[-s, np.full(T, 0.4), np.zeros(T)]]
    return np.stack([paths[p][:, None] + body[None] for p in range(2)])


def _observations(true: Rig, calibrated: Rig, X_p3: np.ndarray, noise_px: float = 0.5) -> Observations:
    """Every camera sees every point (true projections + noise), undistorted with ``calibrated``'s lens."""
    rng = np.random.default_rng(1)
    cam_o, point_o, xy = [], [], []
    for c, cam in enumerate(true):
        uv = cam.project(X_p3) + rng.normal(0, noise_px, (len(X_p3), 2))
        cam_o += [c] * len(X_p3)
        point_o.append(np.arange(len(X_p3)))
        xy.append(uv)
    cam_o, point_o, xy = np.array(cam_o), np.concatenate(point_o), np.concatenate(xy)
    xn = np.concatenate([calibrated[n].pixels_to_lens(xy[cam_o == c]) for c, n in enumerate(calibrated.names)])
    return Observations(cam_o, point_o, xn, xy, np.ones(len(cam_o)), len(X_p3))


def _relative(rig: Rig, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera i's rotation and centre relative to camera 0 (what the people can tell)."""
    c0, ci = rig.cameras[0], rig.cameras[i]
    return ci.R @ c0.R.T, c0.R @ (ci.center - c0.center)


def _errors(a: Rig, b: Rig) -> list[tuple[float, float]]:
    out = []
    for i in range(1, len(a)):
        Ra, ca = _relative(a, i)
        Rb, cb = _relative(b, i)
        out.append((float(np.degrees(np.linalg.norm(rotvec(Ra @ Rb.T)))), float(np.linalg.norm(ca - cb))))
    return out


def test_a_camera_off_by_degrees_comes_back_to_where_the_people_put_it():
    true = make_ring_rig(4, radius=4.0)
    off = true.cameras[2]
    dR = np.array([[np.cos(0.07), 0, np.sin(0.07)], [0, 1, 0], [-np.sin(0.07), 0, np.cos(0.07)]])  # 4 deg pan
    bad = off.copy(R=dR @ off.R, t=dR @ off.t + np.array([0.08, 0.0, 0.0]))
    calibrated = Rig([bad if c.name == off.name else c for c in true])
    X = _people().reshape(-1, 3)
    refined, report = refine_poses(calibrated, _observations(true, calibrated, X))
    before, after = _errors(calibrated, true), _errors(refined, true)
    assert max(d for d, _ in before) > 3.5
    assert max(d for d, _ in after) < 0.3 and max(m for _, m in after) < 0.03, (before, after)
    obs = _observations(true, calibrated, X)
    assert cameras_off(calibrated, obs, report)[0] == ["cam2"], report
    held, _ = refine_poses(calibrated, _observations(true, calibrated, X), free=["cam2"])
    assert max(d for d, _ in _errors(held, true)) < 0.3 and held["cam0"].R is not None
    assert np.allclose(held["cam0"].center, calibrated["cam0"].center, atol=0.01)
    r = report["cameras"]["cam2"]
    assert r["median_px_before"] > 4 and r["median_px_after"] < 0.7 and r["turned_deg"] > 1.5, report


def test_a_right_calibration_stays_where_it_is():
    true = make_ring_rig(4, radius=4.0)
    obs = _observations(true, true, _people().reshape(-1, 3))
    refined, report = refine_poses(true, obs)
    assert all(d["turned_deg"] < 0.1 and d["moved_m"] < 0.01 for d in report["cameras"].values()), report
    assert cameras_off(true, obs, report)[0] == [], report


def test_calibrate_people_without_a_match_is_one_clear_line(tmp_path, cli):
    from mamma_kit.core.calibfile import write_calibration
    from mamma_kit.core.io import write_toml

    write_toml(tmp_path / "capture.toml", {"capture": {"name": "p", "people": 2},
                                           "cameras": {c: {"video": f"videos/{c}.mp4"} for c in ("cam0", "cam1")}})
    write_calibration(tmp_path / "calibration.toml", Rig(make_ring_rig(2).cameras))
    r = cli("calibrate", str(tmp_path), "--people")
    assert r.code == 2 and "keypoints/ and identities.json" in r.err and "--to match" in r.err, r
