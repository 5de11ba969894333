"""Identity matching on the recipes' own rigs, clocks and motions: 100 % with noisy ground truth.

The workspaces here hold what `mamma-kit match` reads -- landmarks/<cam>.npz, calibration and
timing -- made from the recipe exactly as `mamma-kit synth` makes its ground truth (the same
rig with lens distortion, unsynchronised VFR clocks, bodies and motion via mamma_kit.synth),
but without rendering pixels, which matching never looks at: each camera's 512 landmarks are
projected at its own frame times, and visibility comes from a depth buffer of all people's
vertices (a landmark is visible when nothing lies 4 cm in front of it). Noise is then added by
the real `mamma-kit landmarks --source gt --noise 1.2% --outliers 0.05` (1.2 % of the box height,
5 % outliers), and the real `mamma-kit match` and `mamma-kit eval` run on the result.
(benchmarks/match_accuracy.py does the same on fully rendered captures.)
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from mamma_kit.core.calibfile import write_calibration
from mamma_kit.core.io import write_toml
from mamma_kit.core.timingfile import write_timing
from mamma_kit.core.tracks import LandmarkTracks

FRAMES = 8  # scene frames of action; each camera adds its own lead-in
ZBUF_SIDE = 200  # depth-buffer width (px)


def depth_visibility(cam, verts_pv3: list[np.ndarray], lms_pl3: np.ndarray, tol: float = 0.04) -> np.ndarray:
    """(P, L) bool: landmark not hidden behind any person's surface, and inside the image."""
    w, h = cam.size
    f = ZBUF_SIDE / w
    bw, bh = ZBUF_SIDE, max(1, int(round(h * f)))
    V = np.concatenate(verts_pv3)
    z = cam.to_camera(V)[:, 2]
    uv = cam.project(V) * f
    ok = np.isfinite(uv).all(1) & (z > 0)
    iu, iv = np.round(uv[ok, 0]).astype(int), np.round(uv[ok, 1]).astype(int)
    inside = (iu >= 0) & (iu < bw) & (iv >= 0) & (iv < bh)
    zbuf = np.full(bh * bw, np.inf)
    np.minimum.at(zbuf, iv[inside] * bw + iu[inside], z[ok][inside])
    zbuf = zbuf.reshape(bh, bw)
    import scipy.ndimage as ndi

    zbuf = ndi.minimum_filter(np.where(np.isfinite(zbuf), zbuf, 1e9), 2)  # close splat gaps
    P, L = lms_pl3.shape[:2]
    zl = cam.to_camera(lms_pl3)[..., 2]
    xy = cam.project(lms_pl3)
    in_img = np.isfinite(xy).all(-1) & (xy[..., 0] >= -0.5) & (xy[..., 0] < w - 0.5) & \
        (xy[..., 1] >= -0.5) & (xy[..., 1] < h - 0.5)
    bu = np.clip(np.round(np.nan_to_num(xy[..., 0]) * f).astype(int), 0, bw - 1)
    bv = np.clip(np.round(np.nan_to_num(xy[..., 1]) * f).astype(int), 0, bh - 1)
    return in_img & (zl <= zbuf[bv, bu] + tol)


def recipe_workspace(root, recipe_name: str, frames: int = FRAMES):
    """A workspace with gt/landmarks, gt/calibration.toml and gt/timing.toml of a recipe."""
    from mamma_kit.synth.recipe import load_recipe
    from mamma_kit.synth.rig import build_rig, rig_of
    from mamma_kit.synth.scene import build_scene

    recipe = load_recipe(recipe_name)
    recipe.duration_s = frames / recipe.fps
    cams = build_rig(recipe)
    scene = build_scene(recipe, cams)
    lm_ids = scene.body.landmark_ids
    P = scene.n_people
    for sc in cams:
        cam = sc.camera
        verts, _ = scene.pose(sc.scene_times)  # (P, T, V, 3)
        T = len(sc.frame_times)
        lt = LandmarkTracks.empty(cam.name, cam.size, sc.frame_times, np.arange(P), len(lm_ids), "open:gt", "gt")
        for t in range(T):
            lms = verts[:, t][:, lm_ids]  # (P, L, 3)
            vis = depth_visibility(cam, [verts[p, t, ::3] for p in range(P)], lms)
            xy = cam.project(lms)
            lt.xy[t] = xy
            lt.sigma[t] = 0.0
            lt.visibility[t] = vis
            lt.valid[t] = vis.any(1)
        lt.save(root / "gt" / "landmarks" / f"{cam.name}.npz")
    write_calibration(root / "gt" / "calibration.toml", rig_of(cams))
    write_timing(root / "gt" / "timing.toml", {c.camera.name: c.clock for c in cams}, "scene", "gt")
    write_toml(root / "capture.toml", {"capture": {"name": recipe_name},
                                       "cameras": {c.camera.name: {"video": f"videos/{c.camera.name}.mp4"}
                                                   for c in cams}})
    return [c.camera.name for c in cams]


def run_match(cli, root, cams):
    r = cli("match", root, "--cameras", ",".join(cams), "--calibration", root / "gt" / "calibration.toml",
            "--timing", root / "gt" / "timing.toml", "--force", "--json")
    assert r.code == 0, r
    r = cli("eval", root, "--only", "identities", "--json")
    assert r.code == 0, r
    return json.loads(r.out)["identities"]


@pytest.fixture(scope="module")
def crowd(tmp_path_factory):
    root = tmp_path_factory.mktemp("crowd6")
    return root, recipe_workspace(root, "crowd-6")


@pytest.fixture(scope="module")
def duo(tmp_path_factory):
    """iphone-outdoor-duo without the synth's arm IK that joins the dancers' hands exactly (minutes
    of L-BFGS on two shared cores); the dance keeps them close. benchmarks/match_accuracy.py
    uses the fully rendered capture, hands joined."""
    root = tmp_path_factory.mktemp("duo")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("mamma_kit.synth.interact.solve_contacts", lambda body, clip, iters: 0.0)
        return root, recipe_workspace(root, "iphone-outdoor-duo")


def _noisy(cli, root):
    r = cli("landmarks", root, "--source", "gt", "--noise", "1.2%", "--outliers", "0.05", "--seed", "3", "--quiet")
    assert r.code == 0, r


@pytest.mark.parametrize("n_cams", [8, 3])
def test_crowd6_identities_100_percent(crowd, cli, n_cams):
    root, cams = crowd
    _noisy(cli, root)
    sub = cams[:: len(cams) // n_cams][:n_cams] if n_cams < len(cams) else cams
    res = run_match(cli, root, sub)
    assert res["gt_persons"] == 6
    assert res["accuracy"] == 1.0, res
    assert res["persons_split"] == 0 and res["persons_merged"] == 0
    ident = json.loads((root / "identities.json").read_text())
    assert len(ident["persons"]) == 6 and all(p["views"] == n_cams for p in ident["persons"])


@pytest.mark.parametrize("n_cams", [4, 2])
def test_duo_identities_100_percent(duo, cli, n_cams):
    root, cams = duo
    _noisy(cli, root)
    res = run_match(cli, root, cams[:n_cams])
    assert res["gt_persons"] == 2
    assert res["accuracy"] == 1.0, res
    ident = json.loads((root / "identities.json").read_text())
    assert [p["views"] for p in ident["persons"]] == [n_cams, n_cams]
    assert (root / "report" / "match" / "affinities.png").stat().st_size > 5000


def test_broken_track_rejoins_its_person(duo, cli):
    """A person's track that breaks in one view and restarts under a new id joins the same person."""
    root, cams = duo
    _noisy(cli, root)
    path = root / "landmarks" / f"{cams[1]}.npz"
    lt = LandmarkTracks.load(path)
    T = len(lt.frame_times)
    cut = T // 2
    # person 0 in cams[1]: frames < cut keep id 0, frames >= cut become track 7
    k = int(np.flatnonzero(lt.track_ids == 0)[0])
    fields = ("xy", "sigma", "visibility", "contact", "floor_contact")
    new = {f: np.concatenate([getattr(lt, f), getattr(lt, f)[:, k:k + 1]], 1) for f in fields}
    valid = np.concatenate([lt.valid, lt.valid[:, k:k + 1]], 1)
    valid[cut:, k] = False
    valid[:cut, -1] = False
    lt2 = LandmarkTracks(lt.camera, lt.image_size, lt.frame_times, np.r_[lt.track_ids, 7], valid, **new)
    lt2.save(path)
    run_match(cli, root, cams)
    ident = json.loads((root / "identities.json").read_text())
    a = ident["assignments"][cams[1]]
    assert a["7"] == a["0"] != a["1"]
    others = {ident["assignments"][c]["0"] for c in cams if c != cams[1]}
    assert others == {a["0"]}


def test_match_user_errors(duo, cli, tmp_path):
    root, cams = duo
    _noisy(cli, root)
    r = cli("match", root)  # no calibration.toml in the workspace
    assert r.code == 2 and "calibration" in r.err and "Traceback" not in r.err
    r = cli("match", root, "--calibration", root / "gt" / "calibration.toml", "--cameras", cams[0])
    assert r.code == 2 and "at least two cameras" in r.err
    r = cli("match", root, "--calibration", root / "gt" / "calibration.toml", "--cameras", "cam0,nope")
    assert r.code == 2 and "nope" in r.err
    r = cli("match", root, "--calibration", root / "gt" / "calibration.toml", "--timing", tmp_path / "t.toml")
    assert r.code == 2 and "timing file not found" in r.err
