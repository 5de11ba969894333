"""Synthetic rooms: furniture that hides people and stays out of their way, a wall that hides what
is behind it, and people who leave through a door and come back."""

from __future__ import annotations

import numpy as np
import pytest

from mamma_kit.core.errors import UserError
from mamma_kit.synth.recipe import load_recipe
from mamma_kit.synth.render import CameraRenderer, PersonMesh


@pytest.fixture(scope="module")
def room():
    from mamma_kit.synth.rig import build_rig
    from mamma_kit.synth.scene import build_scene

    recipe = load_recipe("room-wander")
    recipe.render["scale"] = 0.1  # 128x72: enough to see who hides whom
    cams = build_rig(recipe)
    return recipe, cams, build_scene(recipe, cams)


def test_furniture_stands_where_nobody_walks(room):
    from mamma_kit.synth.props import CLEARANCE_M

    recipe, cams, scene = room
    assert len(scene.env.props) == recipe.scene["chairs"] + recipe.scene["tables"]
    paths = scene.clip.params["transl"][..., :2].reshape(-1, 2)
    for prop in scene.env.props:
        centre = prop.verts[:, :2].mean(0)
        assert np.linalg.norm(paths - centre, axis=1).min() > CLEARANCE_M - 0.3
        assert 0.4 < prop.verts[:, 2].max() < 1.3  # chairs and tables, not walls


def test_two_people_leave_the_room_and_come_back(room):
    recipe, _, scene = room
    r_pt = np.linalg.norm(scene.clip.params["transl"][..., :2], axis=-1)  # (P, T)
    out = r_pt > recipe.scene["room_radius_m"] + 0.3
    assert out.any(1).sum() == recipe.motion["leave"]
    for p in np.flatnonzero(out.any(1)):
        assert not out[p, 0] and not out[p, -1]  # in at the start and back at the end
    assert (np.diff(r_pt, axis=1).std(1) > 0).all()  # everybody moves


def _box(centre_xy, size: float) -> PersonMesh:
    import trimesh

    box = trimesh.creation.box(extents=[size, size, 1.7])
    box.apply_translation([centre_xy[0], centre_xy[1], 0.85])
    return PersonMesh(np.asarray(box.vertices, float), np.asarray(box.faces), np.full((8, 3), 0.5))


def test_furniture_and_wall_hide_what_is_behind_them(room):
    _, cams, scene = room
    for sc in cams:  # a camera that sees furniture
        ren = CameraRenderer(sc.camera, scene.env)
        prim, tfar, _, _ = ren.props.cast(ren.origin, ren.dirs)
        if (prim >= 0).sum() > 20:
            break
    cam = sc.camera
    w, h = cam.size
    assert np.isfinite(ren.render([])[0].depth).mean() > 0.5  # floor, wall and furniture below the wall top
    # a person-sized box 1 m behind a furniture pixel, on the same ray: that pixel stays furniture
    hit = np.flatnonzero(prim >= 0)
    X_n3 = ren.origin + ren.dirs[hit] * (tfar[hit] + 0.6)[:, None]
    inside = np.linalg.norm(X_n3[:, :2], axis=1) < scene.env.radius - 1.0
    i, X = hit[inside][0], X_n3[inside][0]
    fr, _ = ren.render([_box(X[:2], 0.5)])
    inst = fr.instance.ravel()
    assert inst[i] == -1
    assert (inst == 0).any()  # the box is seen around the furniture
    # a box outside the wall, straight ahead of the camera, is hidden by the wall
    ahead = cam.R[2][:2] / np.linalg.norm(cam.R[2][:2])
    fr2, _ = ren.render([_box(cam.center[:2] + ahead * 14.0, 0.6)])
    assert not (fr2.instance == 0).any()
    fr3, _ = ren.render([_box(cam.center[:2] + ahead * 3.0, 0.6)])  # inside: seen
    assert (fr3.instance == 0).any()


def test_a_person_at_the_camera_is_drawn(room):
    """A body beside or at the camera (someone walking past it in a small room) covers every pixel
    whose ray meets it, though the lens model's pixels of its far-off-axis parts are meaningless
    (this rig's barrel distortion folds them back into the frame) or undefined (behind the lens)."""
    import trimesh

    from mamma_kit.synth.render import PeopleScene

    _, cams, scene = room
    cam = cams[0].camera
    ren = CameraRenderer(cam, scene.env)
    static_depth = ren.render([])[0].depth.ravel()
    # (sideways, ahead) in metres in the camera frame, for a box 0.6 m wide, 1.2 m tall, 0.6 m deep
    for side_m, ahead_m in ((0.0, 0.0), (0.0, 0.3), (0.9, 0.6), (-0.7, 0.4), (0.5, 1.2)):
        T_cam_box = np.eye(4)
        T_cam_box[:3, 3] = [side_m, 0.0, ahead_m]
        box = trimesh.creation.box(extents=[0.6, 1.2, 0.6], transform=cam.T_world_cam @ T_cam_box)
        body = PersonMesh(np.asarray(box.vertices, float), np.asarray(box.faces), np.full((8, 3), 0.5))
        fr, _ = ren.render([body])
        prim, tfar, _, _ = PeopleScene([body]).cast(ren.origin, ren.dirs)  # every pixel's ray
        expected = (prim >= 0) & (tfar * ren.cos_z < static_depth)
        assert expected.sum() > 50, (side_m, ahead_m)
        assert np.array_equal(fr.instance.ravel() == 0, expected), (side_m, ahead_m)


def test_room_fields_are_checked(tmp_path):
    import tomli_w

    from mamma_kit.core.io import read_toml
    from mamma_kit.synth.recipe import find_recipe

    rec = read_toml(find_recipe("room-wander"))
    for scene, where in (({"room_radius_m": 3.0}, "room_radius_m"), ({"doors_deg": [10.0]}, "doors_deg"),
                         ({"chairs": -1}, "chairs")):
        path = tmp_path / "r.toml"
        path.write_text(tomli_w.dumps(rec | {"scene": scene}))
        with pytest.raises(UserError, match=f"scene.{where}"):
            load_recipe(path)
    rec["scene"] = {}
    path.write_text(tomli_w.dumps(rec))
    with pytest.raises(UserError, match="motion.leave"):
        load_recipe(path)


@pytest.fixture(scope="module")
def room_ws(tmp_path_factory):
    """room-wander rendered for a second at 128x72, with its ground-truth masks as the tracks."""
    from mamma_kit.cli.app import main

    out = tmp_path_factory.mktemp("room") / "ws"
    for args in (["synth", "room-wander", "--out", str(out), "--frames", "10", "--scale", "0.1", "--no-board"],
                 ["track", str(out), "--backend", "gt", "--no-pictures"]):
        with pytest.raises(SystemExit) as e:
            main(args + ["--quiet"])
        assert e.value.code == 0
    return out


def test_identities_are_scored_per_frame(room_ws):
    """The truth scores 100 % with no switch; a track given the wrong person for its second half
    scores that half wrong and one switch; a track given to a person that is nobody is false."""
    from mamma_kit.core.identities import Identities
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.identities import frame_scores

    ws = Workspace(room_ws)
    cams = ws.load_capture().camera_names
    clocks, _ = read_timing(ws.gt_dir / "timing.toml")
    tracks = {c: MaskTracks.load(ws.mask_file(c)) for c in cams}
    truth = Identities(cams, {c: {int(t): int(t) for t in tracks[c].track_ids} for c in cams})
    r = frame_scores(ws, truth, clocks)
    assert r["matched"] == 1.0 and r["switches"] == 0 and r["wrong"] == 0
    assert not r["false_tracks"] and not r["missed_persons"] and r["persons"] == r["gt_persons"] == 4
    # camera 0's most visible track: its person for the first half, another for the second
    c = cams[0]
    mt = tracks[c]
    k = int(np.argmax(mt.present.sum(0)))
    tid = int(mt.track_ids[k])
    t_ref = clocks[c].to_ref(mt.frame_times[mt.present[:, k]])
    mid = float(np.median(t_ref))
    other = (tid + 1) % 4
    swapped = Identities(cams, truth.assignments, segments={c: [(tid, -1e9, mid, tid), (tid, mid + 1e-6, 1e9, other)]})
    r2 = frame_scores(ws, swapped, clocks)
    assert r2["switches"] == 1 and 0 < r2["wrong"] < 0.5 and r2["matched"] == pytest.approx(1 - r2["wrong"])
    # the switch is the match's (the same track before and after), in that camera, to the other person
    (ev,) = r2["switch_events"]
    assert ev["camera"] == c and ev["tracks"] == [tid, tid] and (ev["from"], ev["to"]) == (tid, other)
    assert r["switch_events"] == []
    assert r2["matched_per_person"][str(tid)] < 1.0


def test_match_draws_who_is_who_in_each_camera(room_ws):
    """`mamma-kit match` writes report/match/<cam>.png: the frame with the most tracks, each track's
    pixels tinted in its person's colour (the picture differs from the video there, not elsewhere)."""
    import cv2

    from mamma_kit.cli.app import main
    from mamma_kit.core.identities import read_identities
    from mamma_kit.core.timingfile import read_timing
    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.matching.pictures import picture_frame
    from mamma_kit.video.reader import VideoReader

    ws = Workspace(room_ws)
    for args in (["landmarks", str(room_ws), "--source", "gt"],
                 ["match", str(room_ws), "--calibration", str(ws.gt_dir / "calibration.toml"),
                  "--timing", str(ws.gt_dir / "timing.toml")]):
        with pytest.raises(SystemExit) as e:
            main(args + ["--quiet"])
        assert e.value.code == 0
    ident = read_identities(ws.identities)
    clocks, _ = read_timing(ws.gt_dir / "timing.toml")
    cap = ws.load_capture()
    checked = 0
    for c in cap.camera_names:
        mt = MaskTracks.load(ws.mask_file(c))
        pic = cv2.cvtColor(cv2.imread(str(ws.report_dir / "match" / f"{c}.png")), cv2.COLOR_BGR2RGB)
        person_tk = ident.person_frames(c, mt.track_ids, clocks[c].to_ref(mt.frame_times))
        t = picture_frame(mt, person_tk)
        _, rgb = VideoReader(cap.cameras[c].video).frame_index(t)
        up = pic.shape[0] // rgb.shape[0]
        assert pic.shape[:2] == (rgb.shape[0] * up, rgb.shape[1] * up)
        small = cv2.resize(pic, (rgb.shape[1], rgb.shape[0]), interpolation=cv2.INTER_AREA).astype(int)
        diff = np.abs(small - rgb.astype(int)).sum(-1)
        people = np.zeros(rgb.shape[:2], bool)
        for k in np.flatnonzero(mt.present[t] & (person_tk[t] >= 0)):
            people |= cv2.erode(mt.mask(t, int(k)).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        if people.sum() > 20:
            assert np.median(diff[people]) > 30  # tinted
            far = cv2.dilate(people.astype(np.uint8), np.ones((9, 9), np.uint8)) == 0
            far[-12:] = False  # the caption line
            assert np.median(diff[far]) < 10  # the rest as the video shows it
            checked += 1
    assert checked >= 2
