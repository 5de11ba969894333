"""Identities over a take (matching/windows.py): a track that jumps to another person is split
where the other views say so, a person whose track broke keeps one identity, a person seen by
one camera or beyond --people is set aside with its reason, and the fit reads the segments."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import landmark_view, make_ring_rig, walking_people
from mamma_kit.core.identities import Identities, read_identities, write_identities
from mamma_kit.matching.match import MatchSettings
from mamma_kit.matching.pairs import ViewTracks
from mamma_kit.matching.windows import WindowSettings, chain_windows, match_take

FPS = 10.0


def take(P=2, T=80, seed=0, cams=3):
    rng = np.random.default_rng(seed)
    rig = make_ring_rig(cams)
    X = walking_people(rng, P, T)
    return rig, X, np.arange(T) / FPS, rng


def views_of(rig, X, times, edit=None):
    out = []
    for c in rig:
        lt = landmark_view(c, X, times)
        if edit is not None:
            lt = edit(c.name, lt) or lt
        out.append(ViewTracks.from_landmarks(lt, c, times))
    return out


def person_at(ident: Identities, cam: str, track: int, t: float) -> int:
    v = ident.person_frames(cam, np.array([track]), np.array([t]))
    return int(v[0, 0])


def test_a_track_that_jumps_to_the_other_person_is_split_where_the_views_say():
    rig, X, times, _ = take()

    def swap(cam, lt):
        if cam == "cam0":  # from frame 40 on, cam0's tracks follow each other's person (a crossing)
            lt.xy[40:] = lt.xy[40:, ::-1].copy()

    ident = match_take(views_of(rig, X, times, swap), None, MatchSettings(), WindowSettings(window_s=1.0))
    assert ident.diagnostics["persons"] == 2
    p_early, p_late = person_at(ident, "cam1", 0, 1.0), person_at(ident, "cam1", 0, 7.0)
    assert p_early == p_late  # cam1's track 0 never jumped: one person
    assert person_at(ident, "cam0", 0, 1.0) == p_early
    assert person_at(ident, "cam0", 0, 7.0) == person_at(ident, "cam1", 1, 7.0) != p_early
    assert {t for t, *_ in ident.segments["cam0"]} == {0, 1}
    assert "cam1" not in ident.segments  # tracks that stay on one person are whole


def test_a_broken_track_keeps_one_identity_and_singletons_and_extra_people_are_set_aside():
    rig, X, times, rng = take(P=3, seed=1)

    def edit(cam, lt):
        if cam == "cam0":  # cam0 loses person 0 for 1.5 s and finds them again as a new track
            from mamma_kit.core.tracks import LandmarkTracks

            out = LandmarkTracks.empty(cam, lt.image_size, lt.frame_times, np.arange(4), lt.n_landmarks)
            out.xy[:, :3], out.visibility[:, :3], out.valid[:, :3] = lt.xy, lt.visibility, lt.valid
            out.xy[50:, 3], out.visibility[50:, 3], out.valid[50:, 3] = lt.xy[50:, 0], 1.0, True
            out.valid[35:, 0] = False
            out.valid[:, 2] = False
            return out
        if cam != "cam1":  # person 2 is seen by cam1 only
            lt.valid[:, 2] = False

    views = views_of(rig, X, times, edit)
    ident = match_take(views, None, MatchSettings(), WindowSettings(window_s=1.0))
    assert ident.diagnostics["persons"] == 2
    assert ident.person_of("cam0", 0) == ident.person_of("cam0", 3) == ident.person_of("cam1", 0)
    why = {(u["camera"], u["track"]): u["reason"] for u in ident.unassigned}
    assert why[("cam1", 2)] == "seen by cam1 only"
    # --people 1 keeps the better seen of the two
    one = match_take(views, None, MatchSettings(), WindowSettings(window_s=1.0, people=1))
    assert one.diagnostics["persons"] == 1
    assert any("--people 1" in u["reason"] for u in one.unassigned)


def test_segments_round_trip_and_reach_the_fit(tmp_path):
    ident = Identities(["a", "b"], {"a": {3: 0}, "b": {7: 0, 8: 1}}, segments={"b": [(8, 0.0, 1.0, 1), (8, 2.0, 3.0, 0)]})
    back = read_identities(write_identities(tmp_path / "identities.json", ident))
    assert back.segments == ident.segments
    pf = back.person_frames("b", np.array([7, 8]), np.array([0.5, 1.5, 2.5]))
    assert pf.tolist() == [[0, 1], [0, -1], [0, 0]]
    assert back.person_frames("a", np.array([3]), np.array([100.0])).tolist() == [[0]]


def test_duplicate_tracks_of_one_person_are_not_a_third_person():
    """Two views each follow one person twice for a while (a tracker's second track on the same
    body): the duplicates match each other, but a person where a better-seen one is at every
    instant is a duplicate, set aside with that reason."""
    from mamma_kit.core.tracks import LandmarkTracks

    rig, X, times, rng = take(P=2, seed=3)

    def edit(cam, lt):
        if cam in ("cam0", "cam1"):
            out = LandmarkTracks.empty(cam, lt.image_size, lt.frame_times, np.arange(3), lt.n_landmarks)
            out.xy[:, :2], out.visibility[:, :2], out.valid[:, :2] = lt.xy, lt.visibility, lt.valid
            out.xy[20:60, 2] = lt.xy[20:60, 0] + rng.normal(0, 1.0, lt.xy[20:60, 0].shape)
            out.visibility[20:60, 2], out.valid[20:60, 2] = 1.0, True
            return out

    ident = match_take(views_of(rig, X, times, edit), None, MatchSettings(), WindowSettings(window_s=1.0))
    assert ident.diagnostics["persons"] == 2
    why = {(u["camera"], u["track"]): u["reason"] for u in ident.unassigned}
    assert "duplicate" in why[("cam0", 2)] and "duplicate" in why[("cam1", 2)]


def test_a_bystander_seen_by_fewer_cameras_than_the_capture_people_is_set_aside():
    """Two people seen by all four cameras, a third by two of them at once at most: the third stands
    outside the cameras' common view, whatever --people says; with three cameras for everyone, all
    three are persons."""
    from mamma_kit.matching.windows import Chain, select_chains

    def chain(cams, frames=20, windows=(0, 1)):
        return Chain({w: {(c, i): frames for i, c in enumerate(cams)} for w in windows}, multiview_frames=2 * frames)

    people = [chain(["a", "b", "c", "d"]), chain(["a", "b", "c", "d"])]
    for n in (None, 3):
        kept, dropped = select_chains(people + [chain(["a", "b"])], 0.1, WindowSettings(people=n), 200)
        assert len(kept) == 2 and "bystander" in dropped[0]["reason"]
    kept, _ = select_chains([chain(["a", "b", "c"]), chain(["a", "b", "c"]), chain(["b", "c", "d"])], 0.1,
                            WindowSettings(), 200)
    assert len(kept) == 3


def test_a_take_read_from_its_files_a_window_at_a_time_gives_the_same_identities(tmp_path):
    """`mamma-kit match` streams each view's landmarks from landmarks/<cam>.npz a window at a time
    (matching.sources): the identities are those of the same views held in memory, a jump placed
    on the same frame."""
    from mamma_kit.core.calibfile import write_calibration
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.matching.match import workspace_views

    rig, X, times, _ = take(P=2, T=60, seed=4)

    def swap(cam, lt):
        if cam == "cam2":
            lt.xy[33:] = lt.xy[33:, ::-1].copy()

    (tmp_path / "ws").mkdir()
    ws = Workspace(tmp_path / "ws")
    ws.landmarks_dir.mkdir(parents=True)
    lts = {}
    for c in rig:
        lt = landmark_view(c, X, times)
        lts[c.name] = swap(c.name, lt) or lt
        lts[c.name].save(ws.landmarks_file(c.name))
    write_calibration(ws.calibration, rig)
    settings = MatchSettings()
    streamed, _, how = workspace_views(ws, [c.name for c in rig], None, None, settings)
    assert how == "frame index"
    in_memory = [ViewTracks.from_landmarks(lts[c.name], c, np.arange(len(times), dtype=float)) for c in rig]
    a = match_take(streamed, None, settings, WindowSettings(window_s=10.0))  # frame index: ten frames
    b = match_take(in_memory, None, settings, WindowSettings(window_s=10.0))
    assert a.assignments == b.assignments and a.segments == b.segments and a.track_frames == b.track_frames
    assert {t for t, *_ in a.segments["cam2"]} == {0, 1}


def test_rows_of_an_npz_are_read_in_any_order(tmp_path):
    from mamma_kit.core.errors import UserError
    from mamma_kit.core.io import NpzRows, write_npz

    rng = np.random.default_rng(0)
    arrays = {"xy": rng.normal(size=(90, 3, 7, 2)).astype(np.float32), "valid": rng.random((90, 3)) > 0.5,
              "f": np.asfortranarray(rng.normal(size=(90, 4)))}  # Fortran order: read whole
    path = write_npz(tmp_path / "a.npz", **arrays)
    with NpzRows(path, tuple(arrays)) as rows:
        assert rows.n_rows == 90
        for a, b in [(0, 10), (5, 20), (40, 52), (50, 61), (3, 4), (85, 200), (0, 90), (0, 30), (10, 50), (12, 13),
                     (20, 70), (60, 61)]:  # a range inside the block kept, then further on
            got = rows.rows(a, b)
            for k, v in arrays.items():
                assert np.array_equal(got[k], v[a:b]), (k, a, b)
    with pytest.raises(UserError, match="missing"):
        NpzRows(path, ("xy", "sigma"))


def _forward_camera(name: str, centre) -> "Camera":
    """A 640x480 camera at ``centre`` looking along world +y (x right, z up)."""
    from mamma_kit.core.camera import Camera

    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    return Camera(name, (640, 480), K, np.zeros(5), "radtan", R, -R @ np.asarray(centre, float))


def test_a_pairing_that_puts_the_person_behind_its_cameras_is_refused():
    # two cameras side by side looking the same way; each sees one person, and the two people stand
    # 3 m apart along the baseline: every landmark of one lies on the epipolar line of the other's,
    # so the pair is epipolar-consistent, but its rays meet 8 m behind both cameras
    from mamma_kit.core.camera import Rig

    rig = Rig([_forward_camera("cam0", [0, 0, 1.6]), _forward_camera("cam1", [2, 0, 1.6])])
    rng = np.random.default_rng(3)
    T = 30
    times = np.arange(T) / FPS
    body = np.c_[rng.normal(0, 0.15, 40), np.full(40, 4.0), rng.uniform(0.0, 1.7, 40)]
    near = np.broadcast_to(body, (T, 1, 40, 3))
    far = near + np.array([3.0, 0, 0])
    views = [ViewTracks.from_landmarks(landmark_view(rig["cam0"], near, times), rig["cam0"], times),
             ViewTracks.from_landmarks(landmark_view(rig["cam1"], far, times), rig["cam1"], times)]
    ident = match_take(views, None, MatchSettings(), WindowSettings())
    assert ident.diagnostics["persons"] == 0
    assert ident.diagnostics["refused"] and all("behind" in r["reason"] for r in ident.diagnostics["refused"])
    # the same cameras seeing one person both: kept
    views = [ViewTracks.from_landmarks(landmark_view(c, near, times), c, times) for c in rig]
    ident = match_take(views, None, MatchSettings(), WindowSettings())
    assert ident.diagnostics["persons"] == 1 and ident.diagnostics["refused"] == []


def test_a_window_person_who_lost_the_assignment_does_not_join_a_chain_in_a_view_it_already_holds():
    # window 0: A and B; window 1: X continues A by cam0's track 1, Y shares only a few frames of
    # cam1's track 1 with A (that track jumped to Y's person) and holds cam0's track 4
    A, B = {("cam0", 1): 20, ("cam1", 1): 20}, {("cam0", 2): 20, ("cam1", 2): 20}
    X, Y = {("cam0", 1): 20, ("cam1", 3): 20}, {("cam1", 1): 5, ("cam0", 4): 20}
    chains = chain_windows([[A, B], [X, Y]], max_gap=2)
    a = next(ch for ch in chains if ("cam0", 1) in ch.windows[0])
    assert a.windows[1] == X  # Y would give the person two cam0 tracks at once
    assert any(ch.windows == {1: Y} for ch in chains)


def test_two_tracks_given_each_others_person_are_swapped_back_where_the_other_fits_far_better():
    # refine_frames alone, with a reject distance no frame exceeds: the chaining gave cam0's two
    # tracks each other's person from frame 65 on; every other view says otherwise
    from mamma_kit.matching.sources import ViewSource
    from mamma_kit.matching.windows import refine_frames

    rig, X, times, _ = take()
    views = [ViewSource.in_memory(v) for v in views_of(rig, X, times)]
    person = {v.name: np.tile(np.arange(2), (len(times), 1)) for v in views}
    person["cam0"][65:] = person["cam0"][65:, ::-1]
    edges = np.r_[times[0] + np.arange(8.0), np.inf]  # 1 s windows
    out = refine_frames(person, views, edges, accept=0.069, reject=10.0)
    assert (out["cam0"] == np.arange(2)).all()
    assert all((out[c] == person[c]).all() for c in ("cam1", "cam2"))


def test_a_chain_near_another_at_a_few_instants_only_is_no_duplicate_of_it():
    # b follows person 0 but took person 1's tracks for two windows (tracks that jumped there): at
    # the instants both are triangulated b is where a is, yet a is alone most of its length
    from mamma_kit.matching.sources import ViewSource
    from mamma_kit.matching.windows import Chain, TrackGeometry

    rig, X, times, _ = take()
    views = [ViewSource.in_memory(v) for v in views_of(rig, X, times)]
    for v in views:
        v.window(-np.inf, np.inf)  # read once: the centroids the geometry triangulates
    geo = TrackGeometry(views, np.r_[times[0] + np.arange(8.0), np.inf])

    def of(person, wins):
        return {w: {(c.name, person): 10 for c in rig} for w in wins}

    a = Chain(of(1, range(6)))
    b = Chain({**of(1, (4, 5)), **of(0, (6, 7))})
    assert not geo.same_place(a, b)
    assert geo.same_place(Chain(of(1, range(2, 6))), a)  # a second chain on a's tracks is one
