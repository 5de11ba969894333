"""Synthetic captures: the ground truth is consistent with what was rendered and recorded."""

from __future__ import annotations

import json
from math import gcd

import numpy as np
import pytest
from scipy import signal

from mamma_kit.core.calibfile import read_calibration
from mamma_kit.core.errors import UserError
from mamma_kit.core.timingfile import read_timing
from mamma_kit.core.tracks import LandmarkTracks, MaskTracks
from mamma_kit.video import VideoReader, read_audio, read_timecode


@pytest.fixture(scope="module")
def tiny_ws(tmp_path_factory):
    """The tiny recipe rendered once through the real CLI (PCM audio, no noise, tmcd, LTC)."""
    import tomli_w

    from mamma_kit.cli.app import main
    from mamma_kit.core.io import read_toml
    from mamma_kit.synth.recipe import find_recipe

    base = tmp_path_factory.mktemp("synth")
    rec = read_toml(find_recipe("tiny"))
    rec["audio"] |= {"codec": "pcm", "snr_db": 80.0, "reverb": "none",
                     "ltc": {"fps": 25.0, "start": "10:00:00:00", "channel": 1}, "tmcd": {"enabled": True}}
    path = base / "tiny-test.toml"
    path.write_text(tomli_w.dumps(rec))
    out = base / "ws"
    with pytest.raises(SystemExit) as e:
        main(["synth", str(path), "--out", str(out), "--json", "--quiet"])
    assert e.value.code == 0
    return out


def test_workspace_layout(tiny_ws):
    for rel in ("capture.toml", "videos/cam0.mov", "videos/cam1.mov", "gt/calibration.toml", "gt/timing.toml",
                "gt/smplx/person_0.npz", "gt/landmarks/cam0.npz", "gt/masks/cam1.npz"):
        assert (tiny_ws / rel).is_file(), rel
    rig, _ = read_calibration(tiny_ws / "gt" / "calibration.toml")
    assert rig.names == ["cam0", "cam1"]
    for cam in rig:
        r = VideoReader(tiny_ws / "videos" / f"{cam.name}.mov")
        assert r.size == cam.size


def test_frame_timestamps_follow_the_clock(tiny_ws):
    clocks, _ = read_timing(tiny_ws / "gt" / "timing.toml")
    for name, clk in clocks.items():
        lt = LandmarkTracks.load(tiny_ws / "gt" / "landmarks" / f"{name}.npz")
        r = VideoReader(tiny_ws / "videos" / f"{name}.mov")
        assert np.abs(r.timestamps - lt.frame_times).max() < 1e-9
        # VFR: the steps are not all equal
        assert np.ptp(np.diff(r.timestamps)) > 1e-5


def test_visible_landmarks_lie_in_their_mask(tiny_ws):
    inside, total = 0, 0
    for name in ("cam0", "cam1"):
        lt = LandmarkTracks.load(tiny_ws / "gt" / "landmarks" / f"{name}.npz")
        mt = MaskTracks.load(tiny_ws / "gt" / "masks" / f"{name}.npz")
        for t in range(len(lt.frame_times)):
            for k in range(len(lt.track_ids)):
                m = mt.mask(t, k)
                vis = lt.visibility[t, k] > 0.5
                if m is None or not vis.any():
                    continue
                px = np.round(lt.xy[t, k, vis]).astype(int)
                px[:, 0] = np.clip(px[:, 0], 0, m.shape[1] - 1)
                px[:, 1] = np.clip(px[:, 1], 0, m.shape[0] - 1)
                # a visible landmark's pixel, or a direct neighbour at a silhouette, is the person's
                hit = m[px[:, 1], px[:, 0]]
                near = np.zeros_like(hit)
                for dy in (-1, 0, 1):
                    for dx in (-1, 0, 1):
                        yy = np.clip(px[:, 1] + dy, 0, m.shape[0] - 1)
                        xx = np.clip(px[:, 0] + dx, 0, m.shape[1] - 1)
                        near |= m[yy, xx]
                inside += int(hit.sum())
                total += len(hit)
                assert near.all()
    assert total > 500
    assert inside / total >= 0.99


def test_occluded_landmarks_are_behind_a_surface(tiny_ws):
    """Re-pose the recipe's bodies and cast a ray to each landmark marked not visible:
    something nearer to the camera is hit, or the landmark is outside the image, or (thin
    parts at low resolution) its pixel shows something else in the rendered mask."""
    from mamma_kit.synth.recipe import load_recipe
    from mamma_kit.synth.render import PeopleScene, PersonMesh
    from mamma_kit.synth.rig import build_rig
    from mamma_kit.synth.scene import build_scene

    recipe = load_recipe(tiny_ws / "gt" / "recipe.toml")
    cams = build_rig(recipe)
    scene = build_scene(recipe, cams)
    checked, behind = 0, 0
    for sc in cams:
        lt = LandmarkTracks.load(tiny_ws / "gt" / "landmarks" / f"{sc.camera.name}.npz")
        mt = MaskTracks.load(tiny_ws / "gt" / "masks" / f"{sc.camera.name}.npz")
        for t in (0, len(sc.frame_times) // 2):
            verts, _ = scene.pose(sc.scene_times[[t]])
            lm = verts[0, 0, scene.body.landmark_ids]
            assert np.abs(sc.camera.project(lm) - lt.xy[t, 0]).max() < 1e-3
            occ = lt.visibility[t, 0] < 0.5
            ps = PeopleScene([PersonMesh(verts[0, 0], scene.body.np.faces, scene.colors[0])])
            v = lm[occ] - sc.camera.center
            dist = np.linalg.norm(v, axis=1)
            prim, tfar, _, _ = ps.cast(sc.camera.center, v / dist[:, None])
            uv = lt.xy[t, 0, occ]
            w, h = sc.camera.size
            outside = (uv[:, 0] < -0.5) | (uv[:, 0] > w - 0.5) | (uv[:, 1] < -0.5) | (uv[:, 1] > h - 0.5)
            occluded = (prim >= 0) & (tfar < dist - 0.005)
            m = mt.mask(t, 0)
            px = np.clip(np.round(np.nan_to_num(uv)).astype(int), 0, [w - 1, h - 1])
            off_mask = ~m[px[:, 1], px[:, 0]]
            assert np.all(outside | occluded | off_mask)
            checked += int(occ.sum())
            behind += int(occluded.sum())
    assert checked > 100 and behind > 0.5 * checked


def test_clap_arrives_where_clock_and_sound_travel_predict(tiny_ws):
    from mamma_kit.synth import audio as sa
    from mamma_kit.synth.recipe import load_recipe
    from mamma_kit.synth.rig import build_rig

    recipe = load_recipe(tiny_ws / "gt" / "recipe.toml")
    cams = build_rig(recipe)
    clap = recipe.claps[0]
    sr = 48000
    g = gcd(sr, sa.SOURCE_RATE)
    # the source waveform the scene used (same seed as the synthesiser)
    src96 = sa.clap_waveform(sa.SOURCE_RATE, np.random.default_rng(recipe.seed + 7))
    src = signal.resample_poly(src96, sr // g, sa.SOURCE_RATE // g)
    pad = sa.CLAP_PAD * sr / sa.SOURCE_RATE
    for sc in cams:
        dist = np.linalg.norm(sc.camera.center - clap.position)
        t_arrive = sc.clock.to_cam(clap.t + dist / sa.SPEED_OF_SOUND)  # camera time
        a = read_audio(tiny_ws / "videos" / f"{sc.camera.name}.mov")
        x = a.channel(0).astype(np.float64)
        xc = signal.correlate(x, src, mode="full")
        lag = int(np.argmax(xc))
        y0, y1, y2 = xc[lag - 1], xc[lag], xc[lag + 1]
        frac = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
        start = lag - (len(src) - 1) + frac + pad  # sample index of the clap onset
        predicted = (t_arrive - a.start_s) * sr
        assert abs(start - predicted) < 1.0, (sc.camera.name, start, predicted)


def test_timecodes_decode_to_the_recipe(tiny_ws):
    from mamma_kit.core.timecode import timecode_to_frames
    from mamma_kit.synth.recipe import load_recipe
    from mamma_kit.synth.rig import build_rig
    from mamma_kit.timing.ltc import decode_ltc

    recipe = load_recipe(tiny_ws / "gt" / "recipe.toml")
    cams = build_rig(recipe)
    for sc in cams:
        name = sc.camera.name
        tc = read_timecode(tiny_ws / "videos" / f"{name}.mov")
        # tmcd: the label of the first frame, whole frames at the recipe's rate from scene time 0
        want = timecode_to_frames("10:00:00:00", recipe.fps) + round(sc.scene_times[0] * recipe.fps)
        assert timecode_to_frames(tc, recipe.fps) == want
        # LTC: every decoded frame starts where its label says, on the scene clock
        a = read_audio(tiny_ws / "videos" / f"{name}.mov")
        fr = decode_ltc(a.channel(1), a.sample_rate, fps_hint=25.0)
        assert fr.n >= 8
        s = sc.clock.to_ref(a.start_s + fr.start_f / a.sample_rate)
        base = timecode_to_frames("10:00:00:00", 25.0)
        assert np.array_equal(fr.count_f, base + np.round(s * 25).astype(int))
        assert np.abs(s * 25 - np.round(s * 25)).max() < 25 / a.sample_rate


def test_synth_cli_json_lists_paths(tiny_ws):
    data = json.loads((tiny_ws / "gt" / "synth.json").read_text())
    assert set(data["paths"]["videos"]) == {"cam0", "cam1"}
    assert data["people"] == 1


def test_bad_recipe_field_is_a_user_error(tmp_path):
    from mamma_kit.synth.recipe import load_recipe

    p = tmp_path / "bad.toml"
    p.write_text('name = "x"\n[rig]\ncount = "four"\n')
    with pytest.raises(UserError, match="rig.count"):
        load_recipe(p)
    p.write_text('name = "x"\n[people]\ncount = 1\n[motion]\nkind = "hug"\n')
    with pytest.raises(UserError, match="people.count = 2"):
        load_recipe(p)


def test_camera_noise_stream_is_the_same_in_every_process():
    """The sensor noise must not depend on Python's per-process string hashing (PYTHONHASHSEED)."""
    import os
    import subprocess
    import sys

    code = "from mamma_kit.synth.scene import camera_rng; print(camera_rng(7, 'cam2').random(3).tolist())"
    outs = {subprocess.run([sys.executable, "-c", code], env={**os.environ, "PYTHONHASHSEED": h}, check=True,
                           capture_output=True, text=True).stdout for h in ("1", "2")}
    assert len(outs) == 1
