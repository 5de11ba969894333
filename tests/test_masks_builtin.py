"""The builtin mask backend on a scene whose truth we draw ourselves: two textured people with
soft contact shadows walk towards each other, cross (one occludes the other) and walk apart,
over a textured floor, with sensor noise, through a real H.264 file.

Outcomes: mean IoU against the drawn masks while people are apart, stable ids through the
crossing, shadows not segmented, and the MaskTracks file round trip through `mamma-kit track`.
"""

from __future__ import annotations

import numpy as np
import pytest

from mamma_kit.core.tracks import MaskTracks
from mamma_kit.core.io import write_toml
from mamma_kit.video.writer import VideoWriter

W, H, T = 256, 160, 48


def _person_mask(cx: float, foot_y: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    """A person-like silhouette (head, torso, legs) -> (mask (H, W), upper-body mask)."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    top = foot_y - height
    head = ((xx - cx) / (0.07 * height)) ** 2 + ((yy - (top + 0.08 * height)) / (0.09 * height)) ** 2 <= 1
    torso = (np.abs(xx - cx) <= 0.14 * height) & (yy >= top + 0.16 * height) & (yy <= top + 0.55 * height)
    legs = (np.abs(np.abs(xx - cx) - 0.07 * height) <= 0.05 * height) & (yy > top + 0.55 * height) & (yy <= foot_y)
    return head | torso | legs, head | torso


def draw_scene(seed: int = 0):
    """Frames (T, H, W, 3) uint8, true masks (T, 2, H, W) and shadow strength (T, H, W) in [0, 0.45];
    person 0 passes in front of person 1."""
    rng = np.random.default_rng(seed)
    import cv2

    base = rng.uniform(90, 160, (H // 8, W // 8, 3))
    bg = cv2.resize(base, (W, H), interpolation=cv2.INTER_CUBIC)
    bg += rng.normal(0, 6, (H, W, 3))
    bg[::16] *= 0.8  # floor tiles
    yy, xx = np.mgrid[0:H, 0:W]
    looks = [(np.array([200, 40, 40]), np.array([40, 60, 170])), (np.array([40, 170, 60]), np.array([60, 50, 40]))]
    frames = np.zeros((T, H, W, 3), np.uint8)
    truth = np.zeros((T, 2, H, W), bool)
    shade = np.zeros((T, H, W))
    for t in range(T):
        u = t / (T - 1)
        xs = [30 + u * (W - 60), W - 30 - u * (W - 60)]
        feet = [150.0, 138.0]  # person 0 nearer the camera (lower in the image, taller)
        hts = [110.0, 96.0]
        img = bg.copy()
        for p in (1, 0):  # far person first, then the near one over it
            m, upper = _person_mask(xs[p], feet[p], hts[p])
            shadow = np.exp(-(((xx - xs[p]) / 22.0) ** 2 + ((yy - feet[p]) / 5.0) ** 2))
            img *= (1 - 0.45 * shadow)[..., None]  # soft contact shadow: darker, same chromaticity
            shade[t] = np.maximum(shade[t], 0.45 * shadow)
            top, bottom = looks[p]
            tex = rng.normal(0, 8, (H, W, 3))
            img[m & upper] = top + tex[m & upper]
            img[m & ~upper] = bottom + tex[m & ~upper]
            truth[t, p] = m
        truth[t, 1] &= ~truth[t, 0]  # occluded part of the far person is not visible
        frames[t] = np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)
    return frames, truth, shade


def write_capture(root, frames, fps: float = 30.0):
    (root / "videos").mkdir(parents=True, exist_ok=True)
    times = np.arange(len(frames)) / fps
    with VideoWriter(root / "videos" / "cam0.mp4", W, H, fps=fps, crf=16) as w:
        for t, f in zip(times, frames):
            w.write_frame(f, float(t))
    write_toml(root / "capture.toml", {"capture": {"name": "drawn"}, "cameras": {"cam0": {"video": "videos/cam0.mp4"}}})
    return times


def _iou(a, b):
    u = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / u if u else 1.0


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """The scene tracked once through the real command (`mamma-kit track --backend builtin`)."""
    from mamma_kit.cli.app import main

    root = tmp_path_factory.mktemp("drawn")
    frames, truth, shade = draw_scene()
    write_capture(root, frames)
    with pytest.raises(SystemExit) as e:
        main(["track", str(root), "--backend", "builtin", "--quiet", "--json"])
    assert e.value.code in (0, None)
    return root, shade, truth, MaskTracks.load(root / "masks" / "cam0.npz")


def _per_person(mt: MaskTracks, truth):
    """IoU per frame and person, using for each person the track that overlaps it most overall."""
    K = len(mt.track_ids)
    overlap = np.zeros((2, K))
    for t in range(T):
        for k in np.flatnonzero(mt.present[t]):
            m = mt.mask(t, k)
            overlap[:, k] += [_iou(m, truth[t, 0]), _iou(m, truth[t, 1])]
    best = overlap.argmax(1)
    iou = np.zeros((T, 2))
    for t in range(T):
        for p in range(2):
            m = mt.mask(t, best[p]) if mt.present[t, best[p]] else np.zeros((H, W), bool)
            iou[t, p] = _iou(m, truth[t, p])
    return best, iou


def _apart(truth):
    import cv2

    k = np.ones((7, 7), np.uint8)
    return np.array([not (cv2.dilate(truth[t, 0].astype(np.uint8), k) & truth[t, 1]).any() for t in range(T)])


def test_separated_people_iou_and_no_shadow(tracked):
    _, shade, truth, mt = tracked
    best, iou = _per_person(mt, truth)
    apart = _apart(truth)
    assert apart.sum() >= 20
    # the first frames are the hardest (nothing known yet): still the target 0.85 on average
    assert iou[apart].mean() >= 0.85, iou[apart].mean()
    # shadows: floor pixels darkened by 15-45 % but not on a person are almost never foreground
    union = np.zeros((T, H, W), bool)
    for t in range(T):
        for k in np.flatnonzero(mt.present[t]):
            union[t] |= mt.mask(t, k)
    import cv2

    near = np.stack([cv2.dilate(truth[t].any(0).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0 for t in range(T)])
    shadow = (shade > 0.15) & ~near  # shadow at least 3 px from a person (edges are another matter)
    assert shadow.sum() > 2000
    assert (union & shadow).sum() / shadow.sum() < 0.05, (union & shadow).sum() / shadow.sum()


def test_ids_survive_the_crossing(tracked):
    _, _, truth, mt = tracked
    best, iou = _per_person(mt, truth)
    assert best[0] != best[1]
    apart = _apart(truth)
    before = np.flatnonzero(apart[: T // 2])
    after = T // 2 + np.flatnonzero(apart[T // 2:])
    # the same track follows each person before and after the crossing
    for p in range(2):
        assert iou[before, p].mean() > 0.7 and iou[after, p].mean() > 0.7, (p, iou[before, p].mean(),
                                                                            iou[after, p].mean())
    # during contact the near (occluding) person keeps most of its mask
    touching = ~apart
    assert iou[touching, 0].mean() > 0.6, iou[touching, 0].mean()


def test_track_cli_writes_masks_and_picture(tracked, cli):
    root, _, truth, mt = tracked
    assert mt.image_size == (W, H) and len(mt.frame_times) == T
    assert np.allclose(mt.frame_times, np.arange(T) / 30.0, atol=1e-3)
    assert (root / "report" / "tracks" / "cam0.png").stat().st_size > 1000
    # second run: inputs unchanged -> skipped, says so
    r2 = cli("track", str(root), "--backend", "builtin", "--json")
    assert r2.code == 0 and "\"skipped\": true" in r2.out, r2


def test_track_cli_user_errors(tracked, cli, tmp_path):
    root = tracked[0]
    r = cli("track", str(root), "--backend", "nope")
    assert r.code == 2 and "unknown --backend" in r.err and "Traceback" not in r.err
    r = cli("track", str(root), "--backend", "gt")
    assert r.code == 2 and "no ground-truth masks" in r.err
    r = cli("track", str(root), "--backend", "sam2")
    assert r.code == 2 and "--sam2-checkpoint" in r.err
    r = cli("track", str(root), "--prompts", str(tmp_path / "p.toml"))
    assert r.code == 2 and "--prompts is for --backend sam2" in r.err
    r = cli("track", str(tmp_path / "missing"))
    assert r.code == 2 and "workspace not found" in r.err


def test_eval_masks_and_gt_backend(tracked, cli, tmp_path):
    """`eval` scores the builtin masks as this file does; `track --backend gt` gives IoU 1."""
    import json
    import shutil

    src, _, truth, mt = tracked
    root = tmp_path / "ws"
    shutil.copytree(src, root)
    masks = {(t, p): truth[t, p] for t in range(T) for p in range(2) if truth[t, p].any()}
    MaskTracks.from_masks("cam0", (W, H), mt.frame_times, np.arange(2), masks).save(root / "gt" / "masks" / "cam0.npz")
    r = cli("eval", root, "--only", "masks", "--json")
    assert r.code == 0, r
    m = json.loads(r.out)["masks"]
    _, iou = _per_person(mt, truth)
    assert abs(m["mean_iou"] - iou.mean()) < 0.02, (m["mean_iou"], iou.mean())
    assert m["mean_iou_separated"] >= 0.85 and m["instances_touching"] > 0
    r = cli("track", root, "--backend", "gt", "--json")
    assert r.code == 0, r
    r = cli("eval", root, "--only", "masks", "--json")
    m = json.loads(r.out)["masks"]
    assert m["mean_iou"] == 1.0 and m["id_switches"] == 0


def test_eval_best_single_track_separates_segmentation_from_identity():
    """Two tracks that swap people (an identity switch) are each given the person they showed
    longest: after the swap both people score 0, while the best single track per frame still
    matches them (1.0)."""
    from mamma_kit.evaluation.masks import compare_camera
    from mamma_kit.masks.base import MaskTrackBuilder

    Hs, Ws, n = 40, 60, 10
    times = np.arange(n) / 10.0
    a = np.zeros((Hs, Ws), bool)
    a[5:35, 5:15] = True
    b = np.zeros((Hs, Ws), bool)
    b[5:35, 40:50] = True
    gt, pred = MaskTrackBuilder("c", (Ws, Hs), times), MaskTrackBuilder("c", (Ws, Hs), times)
    for t in range(n):
        gt.add(t, 0, a, 1.0)
        gt.add(t, 1, b, 1.0)
        pred.add(t, 7, a if t < 6 else b, 1.0)
        pred.add(t, 8, b if t < 6 else a, 1.0)
    e = compare_camera(pred.build(), gt.build(), min_area=10)
    assert np.allclose(e.best_track_iou_tp, 1.0)
    assert np.allclose(e.iou_tp, np.r_[np.ones(6), np.zeros(4)][:, None])
    assert e.switches == 2


def test_rim_pixels_go_to_whoever_covers_most_of_them():
    """A blurred edge (codec, optics) makes the colour test's mask a pixel or two too wide; the rim
    pass keeps a pixel only if the person covers at least half of it, and leaves alone edges whose
    colours are too alike to measure."""
    import cv2

    from mamma_kit.masks.builtin import BuiltinSettings
    from mamma_kit.masks.segment import Background, clean, foreground, refine_rim

    s = BuiltinSettings()
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:H, 0:W]
    truth = ((xx - 90) / 30.0) ** 2 + ((yy - 80) / 50.0) ** 2 <= 1  # the person, hard edge
    bg_rgb = np.array([120.0, 110.0, 100.0])
    for person_rgb, should_change in (([40.0, 140.0, 60.0], True), ([136.0, 104.0, 96.0], False)):
        sharp = np.where(truth[..., None], person_rgb, bg_rgb)
        img = cv2.GaussianBlur(sharp, (0, 0), 1.5) + rng.normal(0, 1.5, sharp.shape)
        img = np.clip(img, 0, 255).astype(np.uint8)
        bg = Background(np.broadcast_to(bg_rgb, (H, W, 3)).astype(np.float32), np.full((H, W), 3.0, np.float32))
        raw = clean(foreground(img, bg, s), H)
        refined = refine_rim(raw, img, bg, s)
        if should_change:
            # the blurred rim is in the colour test's mask, not in the refined one
            assert _iou(refined, truth) > max(0.97, _iou(raw, truth) + 0.03), (_iou(raw, truth), _iou(refined, truth))
        else:  # found by the colour test, but too close to the background to measure a blend
            assert raw.sum() > 0.8 * truth.sum()
            assert (refined == raw).all()


def test_split_follows_colour_regions_not_single_pixels():
    """Two people side by side in one component, both predicted over the whole of it (no motion
    cue): the cut comes from colour alone. Each person's pixels are mostly their own colour with
    a third in a colour both wear; averaged over a neighbourhood the evidence still splits at the
    true boundary, pixel by pixel it frays."""
    from mamma_kit.masks.segment import HIST_BINS, split_component

    rng = np.random.default_rng(5)
    h, w = 120, 80
    comp = np.zeros((h, w), bool)
    comp[10:110, 10:70] = True
    left = np.zeros_like(comp)
    left[:, :40] = True
    n = int(np.prod(HIST_BINS))
    a, b, shared = 5, 70, 120  # colour bins: person A's, person B's, and one both wear
    cidx = np.where(left, a, b)
    cidx = np.where(rng.random((h, w)) < 0.35, shared, cidx)
    hist_a, hist_b = np.full(n, 1e-3), np.full(n, 1e-3)
    hist_a[[a, shared]] = [0.6, 0.4]
    hist_b[[b, shared]] = [0.6, 0.4]
    preds = [comp, comp]
    iou = {}
    for smooth in (0.0, 2.0):
        parts, _ = split_component(comp, preds, [hist_a / hist_a.sum(), hist_b / hist_b.sum()], cidx, 1.0, smooth)
        iou[smooth] = min(_iou(parts[0], comp & left), _iou(parts[1], comp & ~left))
    assert iou[2.0] > 0.97 and iou[2.0] > iou[0.0] + 0.1, iou


def test_matching_shirts_keep_their_upper_bodies_above_their_own_legs():
    """Two people side by side holding hands, the same shirt, different trousers; one track's
    prediction has drifted over half the other's upper body: colour cannot tell the shirts apart
    and the prediction keeps the error (the next frame's prediction carries it on). With the body axes (the columns
    of each one's hips and legs) the upper body goes back above its legs; one person behind the
    other (axes together) leaves the split as it was."""
    from mamma_kit.masks.segment import HIST_BINS, split_component

    a_all, a_up = _person_mask(90.0, 150.0, 120.0)
    b_all, b_up = _person_mask(170.0, 150.0, 120.0)
    arms = np.zeros_like(a_all)
    arms[58:63, 90:171] = True  # hands joined between them, sleeves the shirts' colour
    comp = a_all | b_all | arms
    n = int(np.prod(HIST_BINS))
    shirt, trousers_a, trousers_b = 40, 5, 70
    cidx = np.where(a_all & ~a_up, trousers_a, np.where(b_all & ~b_up, trousers_b, shirt))
    hist_a, hist_b = np.full(n, 1e-3), np.full(n, 1e-3)
    hist_a[[trousers_a, shirt]] = [0.6, 0.4]
    hist_b[[trousers_b, shirt]] = [0.6, 0.4]
    hists = [hist_a / hist_a.sum(), hist_b / hist_b.sum()]
    xx = np.arange(a_all.shape[1])[None, :]
    drifted = a_up & (xx >= 90)  # the half of a's upper body towards b
    preds = [a_all & ~drifted, b_all | drifted | arms]
    share = {}
    for w in (0.0, 0.5):
        parts, _ = split_component(comp, preds, hists, cidx, 1.0, 1.0, axis_weight=w)
        share[w] = (parts[0] & a_up).sum() / a_up.sum()
        assert (parts[1] & b_up).sum() / b_up.sum() > 0.95  # b keeps its own upper body either way
    assert share[0.0] < 0.75 and share[0.5] > 0.9, share
    # one behind the other: the axes coincide, the axis term is off and changes nothing
    c_all, c_up = _person_mask(95.0, 150.0, 120.0)
    behind = [a_all & ~drifted, c_all | drifted]
    comp2 = a_all | c_all
    cid2 = np.where(a_all & ~a_up, trousers_a, np.where(c_all & ~c_up, trousers_b, shirt))
    off, on = (split_component(comp2, behind, hists, cid2, 1.0, 1.0, axis_weight=w)[0] for w in (0.0, 0.5))
    assert all(np.array_equal(x, y) for x, y in zip(off, on))


def test_large_enclosed_background_stays_open():
    """Hole filling restores clothes the background's colour cut out of a person; a large hole is
    floor seen between two people (or legs) with limbs and shadows around it, and stays open."""
    from mamma_kit.masks.segment import enclosed, larger_than

    m = np.zeros((H, W), bool)
    m[20:140, 40:60] = m[20:140, 120:140] = True  # two people
    m[20:30, 40:140] = m[130:140, 40:140] = True  # an arm and a shadow joining them
    m[70:72, 48:50] = False  # a small hole inside the first person
    holes = enclosed(m)
    assert holes[71, 49] and holes[80, 90]
    large = larger_than(holes, 50)
    assert large[80, 90] and not large[71, 49]
    assert large.sum() == 100 * 60


def test_a_track_lets_go_of_a_second_person():
    """Two people who start as one blob (touching in the first frame) then walk a few pixels apart
    stay one linked component; the track keeps the one its prediction covers and the other gets
    its own track."""
    from mamma_kit.masks.builtin import BuiltinSettings
    from mamma_kit.masks.tracker import Tracker

    tr = Tracker((H, W), BuiltinSettings())
    cidx = np.zeros((H, W), np.int64)
    ids = []
    for t in range(8):
        a, _ = _person_mask(100 - 1.0 * t, 150, 100)
        b, _ = _person_mask(130 + 1.0 * t, 140, 90)
        out = tr.step(t, a | b, cidx)
        owner = {k: (np.count_nonzero(m & a), np.count_nonzero(m & b)) for k, (m, _) in out.items()}
        ids.append(owner)
    first, last = ids[0], ids[-1]
    assert len(first) == 1  # one blob: one track
    assert len(last) == 2
    for k, (on_a, on_b) in last.items():
        assert min(on_a, on_b) == 0 and max(on_a, on_b) > 500, last


def _tracker_with(masks: dict, people: int | None = None):
    """A Tracker whose tracks (id -> mask) were all seen, standing still, in frame 0."""
    from mamma_kit.masks.builtin import BuiltinSettings
    from mamma_kit.masks.tracker import Track, Tracker, centroid

    tr = Tracker((H, W), BuiltinSettings(people=people))
    for k, m in masks.items():
        tr.tracks[k] = Track(k, m, centroid(m), last_seen=0, area=float(m.sum()))
    tr.next_id = max(masks) + 1
    return tr


def test_a_track_seen_whole_leaves_its_ghost_behind():
    """A track whose person stands alone (a component only it claims) but whose last mask still
    holds a patch where it was hidden behind someone else takes no share of that other person."""
    a, _ = _person_mask(60, 150, 100)
    b, _ = _person_mask(170, 150, 100)
    ghost = np.zeros_like(b)
    ghost[80:110, 160:180] = True  # a patch inside b's torso, well over the claim threshold
    tr = _tracker_with({0: a | (ghost & b), 1: b})
    out = tr.step(1, a | b, np.zeros((H, W), np.int64))
    assert np.count_nonzero(out[0][0] & b) == 0
    assert np.count_nonzero(out[1][0] & b) == np.count_nonzero(b)


def test_head_count_makes_room_by_joining_one_persons_top_and_bottom():
    """Three people said; one track holds two people a few pixels apart, two tracks hold the top
    and the legs of a third. The legs and top become one track so the pair can part."""
    a, _ = _person_mask(70, 150, 100)
    b, _ = _person_mask(101, 145, 90)
    c, c_top = _person_mask(200, 150, 100)
    from mamma_kit.masks.segment import components

    assert len(components(a | b, 10, 2)) == 1 and len(components(a | b, 10)) == 2  # linked, not touching
    tr = _tracker_with({0: a | b, 1: c_top, 2: c & ~c_top}, people=3)
    out = tr.step(1, a | b | c, np.zeros((H, W), np.int64))
    assert len(out) == 3
    holders = {name: [k for k, (m, _) in out.items() if np.count_nonzero(m & p) > 0.5 * p.sum()]
               for name, p in (("a", a), ("b", b), ("c", c))}
    assert all(len(v) == 1 for v in holders.values()), holders
    assert len({v[0] for v in holders.values()}) == 3, holders


def test_specks_leave_with_the_person_they_are_next_to():
    """When a track frees a person, the specks too small to be components go with whichever piece
    is nearer: left behind, they would widen the track's box and glue the person back."""
    from mamma_kit.masks.tracker import crumbs_of

    piece = np.zeros((H, W), bool)
    piece[40:120, 40:70] = True
    rest = np.zeros((H, W), bool)
    rest[40:120, 150:180] = True
    near_piece, near_rest = np.zeros((H, W), bool), np.zeros((H, W), bool)
    near_piece[60:62, 74:76] = True
    near_rest[60:62, 144:146] = True
    got = crumbs_of(piece, piece | rest | near_piece | near_rest, 20)
    assert np.array_equal(got, near_piece)


def test_two_people_who_came_as_one_blob_are_split_back_to_the_start():
    """The blob of two people touching in the first frames has one track until they part; then the
    frames before are tracked again backwards from the parting (tracker.split_back), and each
    person keeps their own mask from the first frame (the forward pass alone gave them one)."""
    from mamma_kit.masks.builtin import BuiltinSettings
    from mamma_kit.masks.tracker import Tracker, parted_from, split_back

    s = BuiltinSettings()
    tr = Tracker((H, W), s)
    cidx = np.zeros((H, W), np.int64)
    people, frames, prev = [], [], {}
    for t in range(8):
        a, _ = _person_mask(100 - 1.0 * t, 150, 100)
        b, _ = _person_mask(130 + 1.0 * t, 140, 90)
        out = tr.step(t, a | b, cidx)
        born = [k for k in out if k >= tr.next_id_at_frame_start]
        if t and born:
            k_old = parted_from(born[0], out, prev)
            assert k_old is not None and k_old in out
            fixed = split_back({k_old: out[k_old][0], born[0]: out[born[0]][0]}, cidx,
                               [(tj, fj, cidx) for tj, fj in reversed(frames)], s)
            assert sorted(fixed) == list(range(t))  # every frame before the parting
            k_a = max(out, key=lambda k: np.count_nonzero(out[k][0] & a))  # who holds a at the parting
            for tj, fr in fixed.items():
                a_j, b_j = people[tj]
                # each track holds mostly one person: its own 85 %, the other's at most 15 %
                own = {k: max(np.count_nonzero(m & a_j) / a_j.sum(), np.count_nonzero(m & b_j) / b_j.sum())
                       for k, (m, _) in fr.items()}
                other = {k: min(np.count_nonzero(m & a_j) / a_j.sum(), np.count_nonzero(m & b_j) / b_j.sum())
                         for k, (m, _) in fr.items()}
                assert min(own.values()) > 0.85 and max(other.values()) < 0.15, (tj, own, other)
                holds_a = [k for k, (m, _) in fr.items() if np.count_nonzero(m & a_j) > 0.5 * a_j.sum()]
                assert holds_a == [k_a]  # the same track holds a before the parting as at it
            break
        people.append((a, b))
        frames.append((t, a | b))
        prev = out
    else:
        raise AssertionError("the two never parted")


def test_split_back_stops_where_a_person_came_in():
    """A person who walks in next to another (not out of their blob) is not carried back before
    they were there: split_back stops at the first frame where a seed finds nothing."""
    from mamma_kit.masks.builtin import BuiltinSettings
    from mamma_kit.masks.tracker import split_back

    a, _ = _person_mask(100, 150, 100)
    b, _ = _person_mask(200, 150, 100)
    earlier = [(2, a | b, np.zeros((H, W), np.int64)), (1, a, np.zeros((H, W), np.int64)),
               (0, a, np.zeros((H, W), np.int64))]
    fixed = split_back({0: a, 1: b}, np.zeros((H, W), np.int64), earlier, BuiltinSettings())
    assert sorted(fixed) == [2]
