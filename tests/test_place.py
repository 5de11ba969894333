"""`mamma-kit place`: what a camera sees of each fitted body (the bodies' z-buffer), who is tried in
a view, whether they are placed there or name a track that already shows them, and a track that
shows another fitted person than its own given that person for the frame."""

from __future__ import annotations

import numpy as np

from mamma_kit.core.camera import Camera
from mamma_kit.core.tracks import MaskTracks, rle_decode
from mamma_kit.placing.silhouettes import front_labels, visible_silhouette
from mamma_kit.placing.stage import candidates, doubtful, place_camera, relabel_frames

CAM = Camera("cam0", (320, 240), [[200, 0, 159.5], [0, 200, 119.5], [0, 0, 1]])


def slab(cx: float, z: float, w: float = 0.5, h: float = 1.7, n: int = 80) -> np.ndarray:
    """A dense grid of points on a plane facing the camera: a body's stand-in (V, 3)."""
    xs, ys = np.meshgrid(np.linspace(cx - w / 2, cx + w / 2, n), np.linspace(-h / 2, h / 2, 3 * n))
    return np.c_[xs.ravel(), ys.ravel(), np.full(xs.size, z)]


FRONT, BACK = slab(0.0, 4.0), slab(0.3, 6.0)  # the one behind shows right of the front one


def test_the_nearest_body_holds_each_pixel_and_the_one_behind_keeps_what_shows():
    label, alone = front_labels(CAM, [FRONT, BACK, None], 320, 240)
    assert alone[2] == 0 and (label == 2).sum() == 0  # a body not there at this instant
    shown = int((label == 1).sum())
    assert 0 < shown < 0.8 * alone[1]  # the front body hides part of the back one
    assert (label == 0).sum() == alone[0]  # nothing hides the front one
    # front: x 147-172 px, back: x 161-178 px (splats add 2 px); where both project, the front one
    assert label[120, 165] == 0 and label[120, 177] == 1 and label[120, 100] == -1
    sil = visible_silhouette(label, 1)
    assert sil[120, 177] and not sil[120, 165]


def _masks(track_mask: np.ndarray) -> MaskTracks:
    return MaskTracks.from_masks("cam0", (320, 240), np.array([0.0]), np.array([0]), {(0, 0): track_mask})


def test_a_person_the_view_lost_is_placed_with_the_part_it_sees():
    label, _ = front_labels(CAM, [FRONT, BACK], 320, 240)
    front_mask = visible_silhouette(label, 0)
    placed, relabel = place_camera(CAM, [(0, None)], _masks(front_mask), np.array([[0]]), np.array([[False, True]]),
                                   lambda t: [FRONT, BACK], est=None)
    assert relabel == [] and len(placed) == 1 and placed[0].person == 1 and placed[0].frame == 0
    m = rle_decode(placed[0].mask[0], (320, 240))
    assert np.array_equal(m, visible_silhouette(label, 1))
    assert 0.25 <= placed[0].share < 0.8


def test_a_track_without_a_person_that_shows_them_is_named_instead():
    label, _ = front_labels(CAM, [FRONT, BACK], 320, 240)
    back_mask = visible_silhouette(label, 1)
    placed, relabel = place_camera(CAM, [(0, None)], _masks(back_mask), np.array([[-1]]), np.array([[False, True]]),
                                   lambda t: [FRONT, BACK], est=None)
    assert placed == [] and relabel == [(0, 0, 1)]


def test_a_body_hidden_behind_another_is_not_placed():
    behind = slab(0.0, 6.0, w=0.3, h=1.0)  # wholly inside the front body's outline
    placed, relabel = place_camera(CAM, [(0, None)], _masks(np.zeros((240, 320), bool)), np.array([[-1]]),
                                   np.array([[False, True]]), lambda t: [FRONT, behind], est=None)
    assert placed == [] and relabel == []


def test_who_is_tried_where_two_other_views_follow_them():
    t = np.arange(5) / 10.0
    has = np.ones((5, 2), bool)
    lost = has.copy()
    lost[2:4, 1] = False  # cam0 lost person 1 for two frames
    views = {"cam0": (t, lost, 0.1), "cam1": (t, has, 0.1), "cam2": (t, has, 0.1)}
    want = candidates("cam0", views, t)
    assert want[:, 1].tolist() == [False, False, True, True, False] and not want[:, 0].any()
    views["cam2"] = (t, lost, 0.1)  # one other view only: no depth to trust
    assert not candidates("cam0", views, t).any()


def test_a_track_that_shows_another_person_is_given_them_for_that_frame():
    # the tracker handed the back person's body to the front person's track (person 0) for a frame
    label, _ = front_labels(CAM, [FRONT, BACK], 320, 240)
    back_mask = visible_silhouette(label, 1)
    placed, relabel = place_camera(CAM, [(0, None)], _masks(back_mask), np.array([[0]]), np.array([[False, False]]),
                                   lambda t: [FRONT, BACK], est=None)
    assert placed == [] and relabel == [(0, 0, 1)]


def test_a_second_track_on_a_tracked_body_loses_its_person_for_that_frame():
    label, _ = front_labels(CAM, [FRONT, BACK], 320, 240)
    back_mask = visible_silhouette(label, 1)
    masks = MaskTracks.from_masks("cam0", (320, 240), np.array([0.0]), np.array([0, 1]),
                                  {(0, 0): back_mask, (0, 1): back_mask})
    placed, relabel = place_camera(CAM, [(0, None)], masks, np.array([[1, 0]]), np.array([[False, False]]),
                                   lambda t: [FRONT, BACK], est=None)
    assert placed == [] and relabel == [(0, 1, -1)]


def test_frames_where_a_track_lies_nearer_another_body_are_looked_at():
    bodies = np.array([[[0, 0, 10, 20], [30, 0, 40, 20]]] * 3, float)  # (T, P, 4) projected joints' boxes
    tracks = np.array([[[0, 0, 11, 21]], [[29, 0, 40, 21]], [[29, 0, 40, 21]]], float)  # (T, K, 4)
    person = np.array([[0], [0], [-1]])  # frame 1: person 0's track lies on person 1
    assert doubtful(tracks, person, bodies).tolist() == [False, True, False]


def test_changed_frames_become_segments_of_the_track():
    from mamma_kit.core.identities import Identities

    t_ref = np.arange(6) / 10.0
    present = np.ones((6, 2), bool)
    present[5, 0] = False
    masks = MaskTracks.from_masks("cam0", (4, 4), t_ref, np.array([4, 7]),
                                  {(t, k): np.ones((4, 4), bool) for t in range(6) for k in range(2) if present[t, k]})
    ident = Identities(["cam0"], {"cam0": {7: 3}})
    # track 4 had no person: named in frames 1, 2, 4; track 7 (person 3) shows person 5 in frame 2
    relabel_frames(ident, "cam0", masks, t_ref, [(1, 0, 0), (2, 0, 0), (4, 0, 0), (2, 1, 0)], [5])
    p = ident.person_frames("cam0", np.array([4, 7]), t_ref)
    assert p[:, 0].tolist() == [-1, 5, 5, -1, 5, -1]
    assert p[:, 1].tolist() == [3, 3, 5, 3, 3, 3]
    assert ident.assignments["cam0"] == {4: 5, 7: 3}
