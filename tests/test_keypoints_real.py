"""The `pose` tracker and the keypoints stage on real footage (shared/real/pose2sim-multiperson: four
synchronised portrait cameras, two people, bystanders), and on a video with nobody in it."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from mamma_kit.core.tracks import KeypointTracks, MaskTracks

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "real" / "pose2sim-multiperson"
CAMS = ("cam01", "cam02", "cam03", "cam04")
# frames 40-59: the two people close together, in cam03 one passing behind the other
FIRST, COUNT = 40, 20
LIMBS = np.r_[11:17, 23:29]
BODY = np.r_[0, 11:33]  # nose, shoulders to feet
HAND_REPROJECTION_PCT = 2.0


def clip(src: Path, dst: Path) -> Path:
    from mamma_kit.video import VideoReader
    from mamma_kit.video.writer import write_video

    r = VideoReader(src)
    frames = [img for _, _, img in r.read_indices(range(FIRST, FIRST + COUNT))]
    return write_video(dst, frames, r.timestamps[FIRST:FIRST + COUNT] - r.timestamps[FIRST], fps=60.0, crf=16)


@pytest.fixture(scope="module")
def real_ws(tmp_path_factory):
    if not (REAL / "videos" / "cam01.mp4").is_file():
        pytest.skip(f"{REAL} not present (CI has shared/ beside the repo)")
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.keypoints.stage import run_keypoints
    from mamma_kit.masks.stage import run_track
    from mamma_kit.pipeline import init_workspace

    tmp = tmp_path_factory.mktemp("real")
    vids = [clip(REAL / "videos" / f"{c}.mp4", tmp / f"{c}.mp4") for c in CAMS]
    init_workspace(tmp / "ws", vids, calibration=REAL / "calibration" / "Calib.qca.txt", people=2)
    ws = Workspace(tmp / "ws")
    run_track(ws, backend="pose", people=2, pictures=False)
    run_keypoints(ws, pictures=False)
    return ws


def test_pose_tracker_follows_the_two_people_in_every_view(real_ws):
    """Each view's two longest tracks are the two people, apart and present almost throughout
    (other tracks, bystanders, are the match's to set aside: see the head-count test below)."""
    both = []
    for c in CAMS:
        mt = MaskTracks.load(real_ws.mask_file(c))
        assert len(mt.track_ids) >= 2, f"{c}: {len(mt.track_ids)} tracks"
        k0, k1 = np.argsort(-mt.present.sum(0))[:2]
        both.append(mt.present[:, [k0, k1]].all(1))
        # two different people: their masks barely overlap and their boxes differ
        for t in np.flatnonzero(mt.present[:, [k0, k1]].all(1)):
            a, b = mt.mask(t, k0), mt.mask(t, k1)
            assert (a & b).sum() == 0
    assert np.mean(both) >= 0.95, f"both people tracked in {np.mean(both):.0%} of the (view, frame) pairs"


def box_iou(a_4: np.ndarray, b_4: np.ndarray) -> float:
    iw = max(0.0, min(a_4[2], b_4[2]) - max(a_4[0], b_4[0]))
    ih = max(0.0, min(a_4[3], b_4[3]) - max(a_4[1], b_4[1]))
    union = np.prod(a_4[2:] - a_4[:2]) + np.prod(b_4[2:] - b_4[:2]) - iw * ih
    return float(iw * ih / union) if union > 0 else 0.0


def test_one_track_per_body(real_ws):
    """No two tracks on one walker: at no frame do two tracks' boxes overlap by IoU > 0.6 (the two
    people here pass close, and in cam03 one behind the other)."""
    for c in CAMS:
        mt = MaskTracks.load(real_ws.mask_file(c))
        for t in range(len(mt.frame_times)):
            ks = np.flatnonzero(mt.present[t])
            for a, b in itertools.combinations(ks, 2):
                assert box_iou(mt.boxes[t, a], mt.boxes[t, b]) <= 0.6, \
                    f"{c} frame {t}: tracks {mt.track_ids[a]} and {mt.track_ids[b]} on one body"


def test_two_skeletons_on_one_body_are_one_track():
    """same_bodies: masks of which the smaller lies mostly in the larger are one body, neighbours are
    not (a shared edge of a few pixels), whatever the crops' offsets."""
    from mamma_kit.masks.pose import same_bodies

    body = np.zeros((100, 40), bool)
    body[10:90, 10:30] = True
    upper = body[:60].copy()  # the same body's top, cut where a frame's edge would cut a second skeleton
    neighbour = np.zeros((100, 40), bool)
    neighbour[10:90, 0:12] = True  # overlaps the body by a 2-px column
    own = [(body, (100, 50, 140, 150)), (upper, (100, 50, 140, 110)), (neighbour, (128, 50, 168, 150)), None]
    assert same_bodies(own) == [(0, 1)]


def limb_points_inside(kt: KeypointTracks, masks: MaskTracks) -> float:
    """Share of the visible limb points that fall inside their own track's mask, grown by 2 % of the
    person's height (a point on an outline counts as on it); a point outside the image is outside."""
    import cv2

    inside = []
    for t, k in zip(*np.nonzero(kt.valid)):
        m = masks.mask(t, k)
        if m is None:
            continue
        r = max(1, int(0.02 * (masks.boxes[t, k, 3] - masks.boxes[t, k, 1])))
        m = cv2.dilate(m.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0
        ij = np.round(kt.xy[t, k, LIMBS][kt.visibility[t, k, LIMBS] > 0.5]).astype(int)
        ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < m.shape[1]) & (ij[:, 1] < m.shape[0])
        inside += list(np.where(ok, m[np.clip(ij[:, 1], 0, m.shape[0] - 1), np.clip(ij[:, 0], 0, m.shape[1] - 1)],
                                False))
    return float(np.mean(inside))


def test_keypoints_fall_inside_their_own_track(real_ws):
    for c in CAMS:
        mt = MaskTracks.load(real_ws.mask_file(c))
        kt = KeypointTracks.load(real_ws.keypoints_file(c))
        assert kt.valid.sum() >= 0.95 * mt.present.sum()
        share = limb_points_inside(kt, mt)
        assert share >= 0.9, f"{c}: {share:.0%} of visible limb points inside their track"


def views_of(real_ws):
    """The converted Qualisys rig, each camera's keypoints and masks, and the frames all have."""
    from mamma_kit.core.calibfile import read_calibration

    rig, _ = read_calibration(real_ws.calibration)
    kts = [KeypointTracks.load(real_ws.keypoints_file(c)) for c in CAMS]
    mts = [MaskTracks.load(real_ws.mask_file(c)) for c in CAMS]
    return rig.subset(list(CAMS)), kts, mts, min(len(k.frame_times) for k in kts)


def reprojection_errors(real_ws, perm, points) -> np.ndarray:
    """Points triangulated from the four views and reprojected, errors in % of the person's height
    (its mask's box) where a view's weight > 0.5, with camera c's track perm[c][p] as person p;
    ``points(kt, k, T)`` gives a track's xy (T, N, 2) and weights (T, N)."""
    from mamma_kit.core.camera import triangulate_points

    rig, kts, mts, T = views_of(real_ws)
    out = []
    for p in range(2):
        xy, w = zip(*(points(kts[c], perm[c][p], T) for c in range(4)))
        xy, w = np.nan_to_num(np.stack(xy)), np.stack(w)  # (C, T, N, 2), (C, T, N)
        N = xy.shape[2]
        X = triangulate_points(rig, xy.reshape(4, -1, 2), w.reshape(4, -1)).reshape(T, N, 3)
        proj = rig.project(X)  # (C, T, N, 2)
        h = np.stack([mts[c].boxes[:T, perm[c][p], 3] - mts[c].boxes[:T, perm[c][p], 1] for c in range(4)])
        err = np.linalg.norm(proj - xy, axis=-1) / h[..., None] * 100
        out.append(err[(w > 0.5) & np.isfinite(err) & ((w > 0.5).sum(0) >= 2)[None]])
    return np.concatenate(out)


def body_points(kt, k, T):
    return kt.xy[:T, k], np.where(kt.valid[:T, k, None], kt.visibility[:T, k], 0)


PERMS = [[(0, 1)] + [tuple(q) for q in rest] for rest in itertools.product([(0, 1), (1, 0)], repeat=3)]


def test_keypoints_triangulate_with_the_qualisys_calibration(real_ws):
    """BlazePose's points from the four views, triangulated with the converted Qualisys rig,
    reproject within 3 % of the person's height (a wrong conversion is off by tens of percent)."""
    med = min(np.median(reprojection_errors(real_ws, p, body_points)) for p in PERMS)
    assert med < 3.0, f"median reprojection {med:.2f} % of the person's height"


def test_hands_are_read_with_each_person_and_agree_across_views(real_ws):
    """The keypoints stage reads both hands of every person (MediaPipe's hand landmarker on the ROIs
    BlazePose's hand points give): the model is sure of most hands in these views, and the sure
    hands' 21 points from several views triangulate with the Qualisys rig and reproject within a
    few % of the person's height, the people's tracks paired across views as their bodies pair."""
    from mamma_kit.keypoints.hands import MIN_PRESENCE

    _, kts, _, T = views_of(real_ws)
    for kt in kts:
        assert kt.hand_xy.shape == kt.valid.shape + (2, 21, 2) and kt.hand_presence.shape == kt.valid.shape + (2,)
        assert not (kt.hand_presence[~kt.valid] > 0).any()  # hands only of people found
    sure = np.concatenate([kt.hand_presence[kt.valid] for kt in kts]) > MIN_PRESENCE
    assert sure.mean() > 0.3, f"the hand model is sure of {sure.mean():.0%} of the hands"

    def hand_points(kt, k, T):
        w = np.repeat((kt.hand_presence[:T, k] > MIN_PRESENCE).astype(float), 21, axis=-1)  # (T, 42)
        return kt.hand_xy[:T, k].reshape(T, 42, 2), w

    perm = min(PERMS, key=lambda p: np.median(reprojection_errors(real_ws, p, body_points)))
    err = reprojection_errors(real_ws, perm, hand_points)
    assert len(err) > 500
    print(f"hands: sure {sure.mean():.2f}, {len(err)} points, median {np.median(err):.2f} %, p90 {np.percentile(err, 90):.2f} %")
    assert np.median(err) < HAND_REPROJECTION_PCT, f"median {np.median(err):.2f} % of the person's height"


def test_video_with_nobody_gives_no_tracks_and_an_empty_keypoints_file(tmp_path, cli):
    from mamma_kit.pipeline import init_workspace
    from mamma_kit.video.writer import write_video

    yy, xx = np.mgrid[0:240, 0:320]
    frames = [np.dstack([(xx + 3 * i) % 256, yy % 256, np.full_like(xx, 90)]).astype(np.uint8) for i in range(6)]
    vids = [write_video(tmp_path / f"empty{i}.mp4", frames, np.arange(6) / 30.0) for i in range(2)]
    init_workspace(tmp_path / "ws", vids)
    res = cli("track", str(tmp_path / "ws"), "--backend", "pose", "--json", "--quiet")
    assert res.code == 0, res.err
    res = cli("keypoints", str(tmp_path / "ws"), "--json")
    assert res.code == 0, res.err
    assert "no tracked person" in res.err
    kt = KeypointTracks.load(tmp_path / "ws" / "keypoints" / "empty0.npz")
    assert kt.valid.shape[1] == 0 and len(kt.frame_times) == 6


def test_keypoints_without_masks_says_to_track_first(tmp_path, cli):
    from mamma_kit.pipeline import init_workspace
    from mamma_kit.video.writer import write_video

    vids = [write_video(tmp_path / f"a{i}.mp4", [np.zeros((64, 64, 3), np.uint8)] * 2, [0.0, 1 / 30])
            for i in range(2)]
    init_workspace(tmp_path / "ws", vids)
    res = cli("keypoints", str(tmp_path / "ws"))
    assert res.code == 2 and "run `mamma-kit track" in res.err and "Traceback" not in res.err


def test_an_altered_model_file_stops_the_command_with_one_line(tmp_path, cli, monkeypatch):
    import shutil

    from mamma_kit.keypoints import runtime
    from mamma_kit.pipeline import init_workspace
    from mamma_kit.video.writer import write_video

    vids = [write_video(tmp_path / f"a{i}.mp4", [np.zeros((64, 64, 3), np.uint8)] * 2, [0.0, 1 / 30])
            for i in range(2)]
    init_workspace(tmp_path / "ws", vids)
    models = tmp_path / "models"
    models.mkdir()
    shutil.copy(runtime.MODELS_DIR / runtime.DETECTOR, models / runtime.DETECTOR)
    data = bytearray((runtime.MODELS_DIR / runtime.LANDMARKER).read_bytes())
    data[len(data) // 2] ^= 0x01
    (models / runtime.LANDMARKER).write_bytes(bytes(data))
    monkeypatch.setenv(runtime.MODELS_ENV, str(models))
    res = cli("track", str(tmp_path / "ws"), "--backend", "pose")
    assert res.code == 2 and "altered or corrupt" in res.err and "Traceback" not in res.err
    assert len(res.err.strip().splitlines()) == 1
    (models / runtime.LANDMARKER).unlink()
    res = cli("track", str(tmp_path / "ws"), "--backend", "pose")
    assert res.code == 2 and "keypoint model file missing" in res.err


def test_motion_sync_with_people_standing_still_is_one_clear_line(real_ws):
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.errors import UserError
    from mamma_kit.timing.motion import motion_clocks

    rig, _ = read_calibration(real_ws.calibration)
    kts = {c: KeypointTracks.load(real_ws.keypoints_file(c)) for c in CAMS}
    for kt in kts.values():  # every frame shows the first frame's pose: nothing moves
        kt.xy[:] = kt.xy[:1]
        kt.valid[:] = kt.valid[:1]
        kt.visibility[:] = kt.visibility[:1]
    with pytest.raises(UserError, match="too little shared motion"):
        motion_clocks(kts, rig, "cam01")


def sloppy_masks(mt: MaskTracks, reach_frac: float = 0.08) -> MaskTracks:
    """The pose tracks as a careless tracker would cut them where the people meet: each frame, the
    second person's pixels within ``reach_frac`` of the first person's height of the first person
    are given to the first (a forearm on the wrong side of the cut)."""
    import cv2

    out = {}
    for t in range(len(mt.frame_times)):
        a, b = mt.mask(t, 0), mt.mask(t, 1)
        if a is None or b is None:
            out.update({(t, k): m for k, m in ((0, a), (1, b)) if m is not None})
            continue
        r = max(1, int(reach_frac * (mt.boxes[t, 0, 3] - mt.boxes[t, 0, 1])))
        near = cv2.dilate(a.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)) > 0
        out[(t, 0)], out[(t, 1)] = a | (b & near), b & ~near
    return MaskTracks.from_masks(mt.camera, mt.image_size, mt.frame_times, mt.track_ids, out,
                                 producer={"command": "track --backend builtin"})


def test_touching_masks_are_resplit_by_the_points_and_read_again(real_ws):
    """Where a tracker cut the touching people badly, the keypoints stage re-splits their masks by
    the points it found and reads them again, and masks of the pose tracker (split by skeletons
    already) are left alone. On these real frames the re-read keeps the points on their own person
    about as well as the plain read (frames 40-59: cam02 0.933 -> 0.947, cam03 0.965 -> 0.948,
    cam04 0.963 -> 0.949 inside): it is a gain on the synthetic duo (demo MPJPE 48.7 -> 43.5 mm),
    not on this proxy, so the test holds it to "no worse than 3 points"."""
    from mamma_kit.keypoints.estimator import PoseEstimator
    from mamma_kit.keypoints.stage import keypoints_for_tracks, run_keypoints

    c = "cam03"  # one person passing behind the other
    truth = MaskTracks.load(real_ws.mask_file(c))
    sloppy = sloppy_masks(truth)
    video = real_ws.load_capture().cameras[c].video
    est = PoseEstimator()
    plain, s0 = keypoints_for_tracks(est, sloppy, video, resplit=False)
    again, s1 = keypoints_for_tracks(est, sloppy, video, resplit=True)
    assert s0["read_again"] == 0 and s1["resplit"] == 2 and s1["read_again"] > 0
    assert again.valid.sum() >= plain.valid.sum() - 1
    assert limb_points_inside(again, truth) >= limb_points_inside(plain, truth) - 0.03
    # the pose tracker's own masks: no re-split (its summary says so), nothing read again
    summ = run_keypoints(real_ws, cameras=[c], pictures=False, force=True)["cameras"][0]
    assert summ["resplit"] == 0 and summ["read_again"] == 0


def test_phone_stored_copies_give_the_same_tracks_and_keypoints(real_ws, tmp_path):
    """Issue 41: the same clips as an upright phone stores them (frames 1920x1080 landscape with a
    display rotation, HEVC Main10 in a .mov, AAC; the first 10 frames, three dropped in cam02) and the lab's
    calibration at the codec-padded 1088 columns: the same two tracks per view, keypoints within
    1 % of the person's height of the original's on the frames both have."""
    from mamma_kit.core.tracks import nearest_frames
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.keypoints.stage import run_keypoints
    from mamma_kit.masks.stage import run_track
    from mamma_kit.pipeline import init_workspace
    from mamma_kit.video import VideoReader
    from mamma_kit.video.orientation import Orientation
    from mamma_kit.video.phone import phone_copy

    vids = []
    for c in CAMS:
        src = real_ws.root / "videos" / f"{c}.mp4"
        vids.append(phone_copy(src, tmp_path / f"{c}.MOV", orientation=Orientation(90), crop=(1080, 1920),
                               frames=10, drop=(3, 4, 7) if c == "cam02" else ()))
    info = VideoReader(vids[1]).info
    assert (info.stored_size, info.rotation_deg, info.codec, info.bit_depth, info.has_audio) == \
        ((1920, 1080), 90, "hevc", 10, True)
    assert (info.width, info.height, info.n_frames) == (1080, 1920, 7)
    init_workspace(tmp_path / "ws", vids, calibration=REAL / "calibration" / "Calib.qca.txt", people=2)
    ws = Workspace(tmp_path / "ws")
    run_track(ws, backend="pose", people=2, pictures=False)
    run_keypoints(ws, pictures=False)
    for c in CAMS:
        a_mt, b_mt = MaskTracks.load(real_ws.mask_file(c)), MaskTracks.load(ws.mask_file(c))
        assert len(b_mt.track_ids) >= 2 and len(a_mt.track_ids) >= 2, c
        a, b = KeypointTracks.load(real_ws.keypoints_file(c)), KeypointTracks.load(ws.keypoints_file(c))
        ia = nearest_frames(b.frame_times, a.frame_times)  # the copy's frames in the original
        errs = []
        for tb, ta in enumerate(ia):
            for kb in range(len(b_mt.track_ids)):
                if not b.valid[tb, kb] or not a_mt.present[ta].any():
                    continue
                # the original's track of this person: the one whose box centre is nearest
                cb = b_mt.boxes[tb, kb].reshape(2, 2).mean(0)
                ks = np.flatnonzero(a_mt.present[ta])
                ka = int(ks[np.argmin([np.linalg.norm(a_mt.boxes[ta, k].reshape(2, 2).mean(0) - cb) for k in ks])])
                h = a_mt.boxes[ta, ka, 3] - a_mt.boxes[ta, ka, 1]
                if not a.valid[ta, ka] or np.linalg.norm(a_mt.boxes[ta, ka].reshape(2, 2).mean(0) - cb) > 0.1 * h:
                    continue  # the original did not track this person here
                vis = (a.visibility[ta, ka, BODY] > 0.5) & (b.visibility[tb, kb, BODY] > 0.5)
                errs += list(np.linalg.norm(a.xy[ta, ka, BODY] - b.xy[tb, kb, BODY], axis=1)[vis] / h * 100)
        assert len(errs) > 100, c
        assert np.median(errs) < 1.0, f"{c}: keypoints {np.median(errs):.2f} % of the height from the original's"


def test_without_a_head_count_the_views_agree_on_exactly_the_two_people(real_ws):
    """`--people` is a hint: the pose tracker takes no head count (its settings hold none, so the
    fixture's tracks, made with --people 2, are the tracks made without it: bystanders and fragments
    kept per view), and the match over the take, given none, keeps the two people that two or more
    cameras see at once."""
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.io import read_json
    from mamma_kit.matching.match import MatchSettings
    from mamma_kit.matching.pairs import ViewTracks
    from mamma_kit.matching.windows import WindowSettings, match_take

    for c in CAMS:
        settings = read_json(real_ws.cache_dir / f"track-{c}.json")["settings"]
        assert settings["backend"] == "pose" and settings.get("people") is None, settings
    rig, _ = read_calibration(real_ws.calibration)
    views = []
    for c in CAMS:
        kt = KeypointTracks.load(real_ws.keypoints_file(c))
        views.append(ViewTracks.from_keypoints(kt, rig[c], kt.frame_times))
    ident = match_take(views, None, MatchSettings(), WindowSettings())
    assert ident.diagnostics["persons"] == 2, ident.diagnostics
    assert [len(ident.views_of(p)) for p in ident.person_ids] == [4, 4]
    for u in ident.unassigned:  # whatever else a view tracked is set aside with its reason
        assert u["reason"]


def test_of_two_tracks_on_one_body_the_one_that_was_elsewhere_gives_it_up():
    """give_up: a person passing behind another, whose ROI found the front one, lets the body go
    (their last mask lay elsewhere) even when their track is the older; with no last masks to tell
    them apart, the younger track gives it up."""
    from mamma_kit.masks.pose import give_up

    H, W = 120, 200
    front = np.zeros((H, W), bool)
    front[10:110, 80:120] = True
    behind = np.zeros((H, W), bool)
    behind[10:110, 20:60] = True  # the passer-by's last mask, left of the front person
    crop = front[:, 70:130].copy()
    own = (crop, (70, 0, 130, H))
    assert give_up(3, own, 7, own, {3: behind, 7: front}) == 3  # track 3 is older, but was elsewhere
    assert give_up(3, own, 7, own, {3: front, 7: behind}) == 7
    assert give_up(3, own, 7, own, {}) == 7  # no history: the younger


def _cut_from_cam03(real_ws, tmp_path, keypoints_too: bool = True):
    """A copy of the real workspace, matched, with one person's cam03 track cut out of frames 6-13
    (its masks, and its keypoints too unless told): (ws, ident, person, mask tracks before the cut,
    the frames cut, their masks and limb points)."""
    import shutil

    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.identities import write_identities
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.matching.match import MatchSettings
    from mamma_kit.matching.pairs import ViewTracks
    from mamma_kit.matching.windows import WindowSettings, match_take

    shutil.copytree(real_ws.root, tmp_path / "ws")
    ws = Workspace(tmp_path / "ws")
    rig, _ = read_calibration(ws.calibration)
    views = [ViewTracks.from_keypoints(kt, rig[c], kt.frame_times)
             for c in CAMS for kt in [KeypointTracks.load(ws.keypoints_file(c))]]
    ident = match_take(views, None, MatchSettings(), WindowSettings())
    person = ident.person_ids[0]
    tid = next(t for c, t in ident.tracks_of(person) if c == "cam03")
    mt, kt = MaskTracks.load(ws.mask_file("cam03")), KeypointTracks.load(ws.keypoints_file("cam03"))
    k = list(mt.track_ids).index(tid)
    cut = np.arange(6, 14)
    cut = cut[mt.present[cut, k]]
    assert len(cut) >= 6
    cut_masks = {int(f): mt.mask(int(f), k) for f in cut}
    cut_xy = kt.xy[cut, k].copy()
    mt_before = MaskTracks.load(ws.mask_file("cam03"))
    mt.rle_index[cut, k] = 0
    mt.boxes[cut, k] = np.nan
    mt.save(ws.mask_file("cam03"))
    if keypoints_too:
        kt.valid[cut, k] = False
        kt.xy[cut, k] = np.nan
        kt.save(ws.keypoints_file("cam03"))
    write_identities(ws.identities, ident)
    return ws, ident, person, mt_before, cut, cut_masks, cut_xy


def test_fill_finds_a_person_a_view_lost_where_the_others_see_them(real_ws, tmp_path):
    """`mamma-kit fill` on the real recording: one person's track loses eight frames in cam03 (cut
    out of its masks and keypoints); the other three views see them there, so BlazePose looks where
    their skeleton projects and the frames come back as a track of that person on the same body
    (mask IoU with the cut masks > 0.5, limb joints within 5 % of the person's height), with
    landmarks. The stages after read the view's tracks with the new ones; a match run again makes
    the fill stale, and they read the match's own."""
    from mamma_kit.core import filled
    from mamma_kit.core.identities import write_identities
    from mamma_kit.core.tracks import LandmarkTracks
    from mamma_kit.filling.stage import run_fill

    ws, ident, person, mt, cut, cut_masks, cut_xy = _cut_from_cam03(real_ws, tmp_path)
    res = run_fill(ws)
    assert not res["skipped"] and res["found"] >= len(cut) - 1, res
    fm = MaskTracks.load(ws.fill_file("masks", "cam03"))
    fk = KeypointTracks.load(ws.fill_file("keypoints", "cam03"))
    fl = LandmarkTracks.load(ws.fill_file("landmarks", "cam03"))
    fi = filled.load_identities(ws)
    assert fm.track_ids.min() > mt.track_ids.max()
    height = np.ptp(cut_xy[..., 1], axis=1).max()
    back = 0
    for i, f in enumerate(cut):
        cols = [j for j in np.flatnonzero(fm.present[f]) if fi.person_of("cam03", int(fm.track_ids[j])) == person]
        if not cols:
            continue
        j = cols[0]
        m, was = fm.mask(int(f), j), cut_masks[int(f)]
        assert (m & was).sum() / (m | was).sum() > 0.5, f"frame {f}"
        err = np.nanmedian(np.linalg.norm(fk.xy[f, j, LIMBS] - cut_xy[i, LIMBS], axis=-1))
        assert err < 0.05 * height, f"frame {f}: limb joints {err:.1f} px from the cut ones"
        assert fl.valid[f, j] and np.isfinite(fl.xy[f, j]).all()
        back += 1
    assert back >= len(cut) - 1, f"{back} of {len(cut)} cut frames found again"
    assert len(filled.load_masks(ws, "cam03").track_ids) == len(mt.track_ids) + len(fm.track_ids)
    ident.settings = {**ident.settings, "run": "again"}
    write_identities(ws.identities, ident)  # the match ran again: the fill no longer applies
    assert not filled.fill_is_current(ws)
    assert len(filled.load_masks(ws, "cam03").track_ids) == len(mt.track_ids)


def test_fill_takes_no_body_a_track_of_the_view_already_has_its_skeleton_on(real_ws, tmp_path):
    """The same cut, of the masks only: the track's skeleton stays on the body in those frames (as a
    neighbour's track whose mask did not cover them whole). The person has no mask there, so the
    fill looks, but what it finds is that track's body and it adds nothing on it."""
    from mamma_kit.core import filled
    from mamma_kit.filling.stage import run_fill

    ws, ident, person, mt, cut, cut_masks, cut_xy = _cut_from_cam03(real_ws, tmp_path, keypoints_too=False)
    res = run_fill(ws)
    cam03 = next(r for r in res.get("cameras", []) if r["camera"] == "cam03")
    assert cam03["gaps"] >= len(cut), res  # the person was looked for in the cut frames ...
    fm = filled.load_masks(ws, "cam03")
    new = [j for j, t in enumerate(fm.track_ids) if t > mt.track_ids.max()]
    taken = int(fm.present[np.ix_(cut, new)].sum()) if new else 0
    assert taken == 0, f"{taken} of the {len(cut)} frames' bodies taken from the track that has them"


def test_the_cameras_the_people_show_off_are_refined_after_the_match(real_ws, tmp_path):
    """calibration.people.refine_if_off, as capture-to-smplx runs it after `match`: on the lab's
    calibration the matched people put cam01 off (it stands out against the others' points), so its
    pose is refined, the file as it was kept, and the match asked to run again; looked at again with
    nothing changed, the step is skipped (cached) and asks for nothing."""
    import shutil

    from mamma_kit.calibration.people import refine_if_off
    from mamma_kit.core.calibfile import read_calibration
    from mamma_kit.core.identities import write_identities
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.matching.match import MatchSettings
    from mamma_kit.matching.pairs import ViewTracks
    from mamma_kit.matching.windows import WindowSettings, match_take

    shutil.copytree(real_ws.root, tmp_path / "ws")
    ws = Workspace(tmp_path / "ws")
    rig, _ = read_calibration(ws.calibration)
    views = [ViewTracks.from_keypoints(kt, rig[c], kt.frame_times)
             for c in CAMS for kt in [KeypointTracks.load(ws.keypoints_file(c))]]
    write_identities(ws.identities, match_take(views, None, MatchSettings(), WindowSettings()))
    asked = []
    res = refine_if_off(ws, rematch=lambda: asked.append("match"))
    assert "cam01" in res["refined"] and asked == ["match"], res
    assert (ws.root / "calibration.before-people.toml").is_file()
    turned = {c: d["turned_deg"] for c, d in res["cameras"].items()}
    held = [c for c in CAMS if c not in res["refined"]]
    # a camera that does not stand out is held (it moves only with the similarity that puts the rig
    # back in the calibration's world frame)
    assert held and min(turned[c] for c in res["refined"]) > 2 * max(turned[c] for c in held), turned
    again = refine_if_off(ws, rematch=lambda: asked.append("again"))
    assert again["skipped"] and asked == ["match"]
