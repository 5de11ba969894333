"""capture-to-smplx: stages cached by their inputs, interrupted runs resume with nothing lost,
a changed input recomputes exactly the stages that read it, and `mamma-kit init`.

The workspace is the tiny recipe (2 cameras, 1 person) with its true calibration given (it
has no board session), ground-truth masks and noisy ground-truth landmarks, so the test
exercises the pipeline's bookkeeping in seconds; every stage still runs its real code.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_toml, write_toml

STAGE_SETTINGS = {"track": {"backend": "gt"},
                  "landmarks": {"source": "gt", "noise": "1.2%", "outliers": 0.05, "seed": 0}}


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    from mamma_kit.synth.capture import synthesize

    root = tmp_path_factory.mktemp("pipe") / "template"
    synthesize("tiny", root, board=False)
    shutil.copyfile(root / "gt" / "calibration.toml", root / "calibration.toml")
    cap = read_toml(root / "capture.toml")
    cap["settings"] = STAGE_SETTINGS
    write_toml(root / "capture.toml", cap)
    return root


def _copy(template, dst):
    shutil.copytree(template, dst)
    return dst


def _results(ws_dir) -> dict[str, np.ndarray]:
    d = np.load(ws_dir / "smplx" / "person_0.npz")
    return {k: d[k] for k in ("body_pose", "global_orient", "transl", "betas", "joints")}


@pytest.fixture(scope="module")
def reference(template, tmp_path_factory):
    from mamma_kit.pipeline import capture_to_smplx

    ws = _copy(template, tmp_path_factory.mktemp("ref") / "ws")
    cap = read_toml(ws / "capture.toml")
    cap["settings"]["report"] = {"video": False}
    write_toml(ws / "capture.toml", cap)
    run = capture_to_smplx(ws, progress=False)
    return ws, run


def test_first_run_runs_every_stage_and_second_skips_all(reference):
    from mamma_kit.pipeline import capture_to_smplx

    ws, run = reference
    st = {k: v["status"] for k, v in run["stages"].items()}
    assert st == {"calibrate": "provided", "sync": "ran", "track": "ran", "keypoints": "ran", "landmarks": "ran", "match": "ran",
                  "fill": "skipped", "fit": "ran", "place": "ran", "export": "ran", "report": "ran"}  # fill: nothing to read new tracks with
    assert (ws / "report" / "index.html").is_file() and (ws / "export" / "capture.glb").is_file()
    again = capture_to_smplx(ws, progress=False)
    assert {k: v["status"] for k, v in again["stages"].items()} == {
        "calibrate": "provided", "sync": "skipped", "track": "skipped", "keypoints": "skipped", "landmarks": "skipped", "match": "skipped",
        "fill": "skipped", "fit": "skipped", "place": "skipped", "export": "skipped", "report": "skipped"}
    # the fit recovers the person (the numbers themselves are tested in test_fit_tiny.py)
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.fit import evaluate

    assert evaluate(Workspace(ws))["mpjpe_mm"] < 60


def test_placed_tracks_are_read_while_made_from_the_fit_there(reference, tmp_path):
    from mamma_kit.core.filled import load_identities, place_is_current
    from mamma_kit.core.identities import read_identities
    from mamma_kit.core.workspace import Workspace

    ws = Workspace(_copy(reference[0], tmp_path / "ws"))
    assert place_is_current(ws)
    # two cameras: no view has two others to place a person from
    assert read_identities(ws.place_dir / "identities.json").settings["place"]["person_view_frames"] == 0
    f = ws.person_files()[0]
    f.write_bytes(f.read_bytes() + b"\0")  # another fit: the placement is stale, the loaders leave it out
    assert not place_is_current(ws)
    assert load_identities(ws, placed=True).settings == load_identities(ws).settings


def test_ctrl_c_mid_stage_resumes_and_ends_with_the_same_result(template, reference, tmp_path, monkeypatch):
    """Ctrl-C while the landmarks stage is between its two cameras: the rerun keeps the
    finished stages and camera, redoes the rest, and the fit equals an uninterrupted run's."""
    import mamma_kit.landmarks.gt as lgt
    from mamma_kit.pipeline import capture_to_smplx

    ws = _copy(template, tmp_path / "ws")
    real = lgt.noisy_gt_landmarks
    calls = []

    def interrupted(ws_, cam, *a, **k):
        calls.append(cam)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(ws_, cam, *a, **k)

    monkeypatch.setattr(lgt, "noisy_gt_landmarks", interrupted)
    with pytest.raises(KeyboardInterrupt):
        capture_to_smplx(ws, to_stage="fit", progress=False)
    assert (ws / "landmarks" / "cam0.npz").is_file() and not (ws / "landmarks" / "cam1.npz").exists()
    assert not (ws / "smplx").exists()
    monkeypatch.setattr(lgt, "noisy_gt_landmarks", real)

    run = capture_to_smplx(ws, to_stage="fit", progress=False)
    st = {k: v["status"] for k, v in run["stages"].items()}
    assert st == {"calibrate": "provided", "sync": "skipped", "track": "skipped", "keypoints": "skipped", "landmarks": "ran",
                  "match": "ran", "fill": "skipped", "fit": "ran"}
    cams = {c["camera"]: c["skipped"] for c in run["stages"]["landmarks"]["summary"]["cameras"]}
    assert cams == {"cam0": True, "cam1": False}
    ref = _results(reference[0])
    got = _results(ws)
    for k in ref:
        np.testing.assert_allclose(got[k], ref[k], atol=1e-6, err_msg=k)


def test_killed_process_resumes(template, reference, tmp_path):
    """kill -9 of a running capture-to-smplx during the fit: nothing written is corrupt, the
    rerun reuses every finished stage and fits again."""
    ws = _copy(template, tmp_path / "ws")
    cmd = [sys.executable, "-c", "import sys; from mamma_kit.cli.app import main; main(sys.argv[1:])",
           "capture-to-smplx", str(ws), "--to", "fit", "-q"]
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while not (ws / ".cache" / "match.json").exists():
        assert p.poll() is None, "capture-to-smplx ended before the fit"
        time.sleep(0.05)
    time.sleep(0.3)  # into the fit (several seconds on tiny)
    was_running = p.poll() is None
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    assert was_running and not (ws / ".cache" / "fit.json").exists()
    from mamma_kit.pipeline import capture_to_smplx

    run = capture_to_smplx(ws, to_stage="fit", progress=False)
    st = {k: v["status"] for k, v in run["stages"].items()}
    assert st["fit"] == "ran" and all(st[s] in ("skipped", "provided") for s in
                                      ("calibrate", "sync", "track", "keypoints", "landmarks", "match"))
    ref = _results(reference[0])
    got = _results(ws)
    for k in ref:
        np.testing.assert_allclose(got[k], ref[k], atol=1e-6, err_msg=k)


def test_a_changed_input_recomputes_exactly_what_depends_on_it(template, tmp_path):
    from mamma_kit.pipeline import capture_to_smplx

    ws = _copy(template, tmp_path / "ws")
    capture_to_smplx(ws, to_stage="fit", progress=False)
    cap = read_toml(ws / "capture.toml")
    # new landmark noise: landmarks and everything reading them; not sync, not track
    cap["settings"]["landmarks"]["seed"] = 1
    write_toml(ws / "capture.toml", cap)
    st = {k: v["status"] for k, v in capture_to_smplx(ws, to_stage="fit", progress=False)["stages"].items()}
    assert st == {"calibrate": "provided", "sync": "skipped", "track": "skipped", "keypoints": "skipped", "landmarks": "ran",
                  "match": "ran", "fill": "skipped", "fit": "ran"}
    # a new fit setting: only the fit
    cap["settings"]["fit"] = {"stages": 3}
    write_toml(ws / "capture.toml", cap)
    st = {k: v["status"] for k, v in capture_to_smplx(ws, to_stage="fit", progress=False)["stages"].items()}
    assert st == {"calibrate": "provided", "sync": "skipped", "track": "skipped", "keypoints": "skipped", "landmarks": "skipped",
                  "match": "skipped", "fill": "skipped", "fit": "ran"}
    # an edited output is never silently reused: its stage is redone
    (ws / "identities.json").write_text((ws / "identities.json").read_text() + " ")
    st = {k: v["status"] for k, v in capture_to_smplx(ws, from_stage="match", to_stage="fit",
                                                     progress=False)["stages"].items()}
    assert st == {"match": "ran", "fill": "skipped", "fit": "skipped"}  # same identities again: the fit's inputs are unchanged


def test_bad_settings_and_stage_names_are_user_errors(template, tmp_path):
    from mamma_kit.pipeline import capture_to_smplx

    ws = _copy(template, tmp_path / "ws")
    with pytest.raises(UserError, match="unknown stage"):
        capture_to_smplx(ws, from_stage="fitting")
    cap = read_toml(ws / "capture.toml")
    cap["settings"]["fit"] = {"stagez": 2}
    write_toml(ws / "capture.toml", cap)
    with pytest.raises(UserError, match="unknown keys"):
        capture_to_smplx(ws, from_stage="fit")
    (ws / "calibration.toml").unlink()
    with pytest.raises(UserError, match="no calibration"):
        capture_to_smplx(ws, to_stage="calibrate")


def test_init_links_videos_and_runs(template, tmp_path, cli):
    vids = [template / "videos" / f"cam{i}.mp4" for i in range(2)]
    r = cli("init", tmp_path / "mine", "--videos", *vids, "--names", "left,right", "--json")
    assert r.code == 0, r
    cap = read_toml(tmp_path / "mine" / "capture.toml")
    assert cap["cameras"]["left"]["video"] == "videos/left.mp4"
    assert (tmp_path / "mine" / "videos" / "right.mp4").stat().st_size == vids[1].stat().st_size
    from mamma_kit.core.workspace import Workspace

    assert Workspace(tmp_path / "mine").load_capture().camera_names == ["left", "right"]
    # a second init does not overwrite; a corrupt video is refused before anything is written
    r = cli("init", tmp_path / "mine", "--videos", *vids)
    assert r.code == 2 and "already exists" in r.err
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"\x00" * 1000)
    r = cli("init", tmp_path / "other", "--videos", vids[0], bad)
    assert r.code == 2 and not (tmp_path / "other" / "capture.toml").exists()
