"""Keypoint-guided MammaNet: keypoint inputs in the crop contract, the model's keypoint maps and
prior, training on crops with keypoints, inference through the landmarks stage, and matching that
lets the more reliable of landmarks and keypoints decide."""

import numpy as np
import pytest
import torch
from test_landmarks_cli import ws  # noqa: F401 - the small workspace fixture

from conftest import landmark_view, make_ring_rig, walking_people
from mamma_kit.core.tracks import KeypointTracks, LandmarkTracks
from mamma_kit.landmarks import crop as C
from mamma_kit.landmarks.model import build_model, keypoint_frame, keypoint_maps


def test_keypoint_maps_peak_at_the_point_and_vanish_when_absent():
    H, W = 40, 30
    kp = torch.zeros(1, 2, 5)
    # point 0 at crop pixel (7, 21): normalised n = (u + 0.5) / W * 2 - 1
    kp[0, 0, :2] = torch.tensor([(7 + 0.5) / W * 2 - 1, (21 + 0.5) / H * 2 - 1])
    kp[0, 0, 3:] = torch.tensor([1.0, 1.0])
    m = keypoint_maps(kp, (H, W), 0.05)
    assert m.shape == (1, 2, H, W)
    iy, ix = np.unravel_index(int(m[0, 0].argmax()), (H, W))
    assert (ix, iy) == (7, 21) and float(m[0, 0].max()) == pytest.approx(1.0, abs=1e-5)
    assert float(m[0, 1].abs().max()) == 0.0  # presence 0: no evidence


def test_crop_keypoints_follow_the_crop_affine_and_mark_absent_points():
    box = np.array([100.0, 80.0, 60.0, 80.0])  # cx, cy, bw, bh
    out_wh = (30, 40)
    kp = np.full((3, 5), np.nan)
    kp[0] = [100, 80, 12.0, 0.9, 0.8]  # the box centre
    kp[1] = [70, 40, -3.0, 0.2, 0.95]  # the box's top-left corner
    got = C.crop_keypoints(kp, C.crop_affine(box, out_wh), out_wh)
    assert got[0, :2] == pytest.approx([0, 0], abs=1e-9) and got[1, :2] == pytest.approx([-1, -1], abs=1e-9)
    # z scales like y: image px -> crop px (x 40 / 80) -> normalised (/ 20)
    assert got[0, 2] == pytest.approx(12.0 * 0.5 / 20) and got[0, 3:] == pytest.approx([0.9, 0.8])
    assert (got[2] == 0).all()  # NaN point: absent (presence 0)
    back = C.normalised_to_image(got[:2, :2], box)
    assert back == pytest.approx(kp[:2, :2])


def test_keypoint_prior_moves_and_scales_with_the_points():
    torch.manual_seed(0)
    m = build_model("tiny-kp").eval()
    kp = torch.zeros(1, 33, 5)
    kp[0, :, :2] = torch.rand(33, 2) * 0.8 - 0.4
    kp[0, :, 3:] = 1.0
    with torch.no_grad():
        xy0 = m.prior(kp)["xy"]
        moved = kp.clone()
        moved[0, :, :2] = moved[0, :, :2] * 0.5 + torch.tensor([0.2, -0.1])
        xy1 = m.prior(moved)["xy"]
    # a translated, scaled person gets the same landmark layout translated and scaled
    assert torch.allclose(xy1, xy0 * 0.5 + torch.tensor([0.2, -0.1]), atol=1e-5)
    c, s = keypoint_frame(torch.zeros(1, 33, 5))
    assert torch.allclose(c, torch.zeros(1, 1, 2)) and float(s) == 0.5  # no points: the crop itself


def test_keypoint_model_trains_and_its_prior_learns_from_points(tmp_path):
    """Toy crops whose keypoints are the landmarks themselves (with noise): after a short
    training the keypoint prior alone is much closer to the truth than the crop centre."""
    from test_landmarks_train import L, write_toy_shards

    from mamma_kit.core.io import write_npz
    from mamma_kit.landmarks.augment import AugmentConfig
    from mamma_kit.landmarks.data import CropShards, keypoints_path
    from mamma_kit.landmarks.train import batch_to_torch, make_batch, run_model
    from mamma_kit.landmarks.losses import mammanet_loss

    paths = write_toy_shards(tmp_path / "toy", 96, seed=3, shard_size=48)
    rng = np.random.default_rng(0)
    for p in paths:
        d = np.load(p)
        xy = d["xy"]
        kp = np.full((len(xy), 33, 5), np.nan, np.float32)
        kp[:, :L, :2] = xy + rng.normal(0, 0.5, xy.shape)
        kp[:, :L, 2], kp[:, :L, 3], kp[:, :L, 4] = 0.0, 1.0, 1.0
        write_npz(keypoints_path(p), keypoints=kp, model=np.array("toy"))
    shards = CropShards(tmp_path / "toy")
    assert shards.has_keypoints and shards[0]["keypoints"].shape == (33, 5)
    torch.manual_seed(0)
    m = build_model("tiny-kp")
    opt = torch.optim.AdamW(m.parameters(), lr=3e-3)
    aug = AugmentConfig(p_photometric=0.0, p_blur=0.0, p_noise=0.0, p_jpeg=0.0, p_downup=0.0, p_occluder=0.0,
                        p_mask_corrupt=0.0, p_no_mask=0.0, p_part_crop=0.0)

    from mamma_kit.landmarks.train import prior_pairs, pretrain_prior

    pairs = prior_pairs(shards, m.cfg)
    info = pretrain_prior(m, pairs, 300, batch=64, aug=aug)
    assert info["l1_after"] < 0.35 * info["l1_before"] and info["l1_after"] < 0.08, info
    losses = []
    for step in range(24):  # then the whole network: the refinement starts at the prior's positions
        b = batch_to_torch(make_batch(shards, shards.batch_indices(0, step, 16), m.cfg, aug, (0, step)), "cpu")
        loss, _ = mammanet_loss(run_model(m, b), b)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert np.isfinite(losses).all() and np.mean(losses[-6:]) < np.mean(losses[:6])


def test_landmarks_stage_feeds_the_keypoints_and_asks_for_them(ws, tmp_path, cli):
    from mamma_kit.core.tracks import MaskTracks
    from mamma_kit.landmarks.weights import save_weights
    from test_landmarks_cli import H, T, W, person_rect

    torch.manual_seed(0)
    save_weights(tmp_path / "kp.pt", build_model("tiny-kp"), "toy")
    r = cli("landmarks", ws, "--weights", tmp_path / "kp.pt", "-q")
    assert r.code == 2 and "reads keypoints" in r.err and "mamma-kit keypoints" in r.err
    mt = MaskTracks.load(ws / "masks" / "cam0.npz")
    kt = KeypointTracks.empty("cam0", (W, H), mt.frame_times, mt.track_ids)
    for t in range(T):
        for k, pid in ((0, 1), (1, 0)):
            x1, y1, x2, y2 = person_rect(pid, t)
            kt.valid[t, k] = True
            kt.xy[t, k] = np.stack([np.linspace(x1, x2, 33), np.linspace(y1, y2, 33)], 1)
            kt.z[t, k], kt.visibility[t, k], kt.presence[t, k] = 0.0, 0.9, 0.9
    kt.save(ws / "keypoints" / "cam0.npz")
    assert cli("landmarks", ws, "--weights", tmp_path / "kp.pt", "-q").code == 0
    lt = LandmarkTracks.load(ws / "landmarks" / "cam0.npz")
    assert lt.valid.sum() == mt.present.sum() and np.isfinite(lt.xy[lt.valid]).all()


def test_match_lets_keypoints_decide_where_landmarks_are_noisy():
    from mamma_kit.matching.match import match_views
    from mamma_kit.matching.pairs import ViewTracks

    rng = np.random.default_rng(4)
    rig = make_ring_rig(3)
    T = 12
    X = walking_people(rng, 2, T, L=33)
    times = np.arange(T) / 30
    perms = [np.array([0, 1]), np.array([1, 0]), np.array([0, 1])]
    lm, kp = [], []
    for cam, perm in zip(rig, perms):
        noisy = landmark_view(cam, X, times, perm, noise=400.0, rng=rng)  # landmarks that follow no limb
        lm.append(ViewTracks.from_landmarks(noisy, cam, times))
        good = landmark_view(cam, X, times, perm, noise=1.0, rng=rng)
        kt = KeypointTracks.empty(cam.name, cam.size, times, np.arange(2))
        kt.valid[:], kt.xy[:], kt.visibility[:], kt.presence[:] = True, good.xy, 1.0, 1.0
        kp.append(ViewTracks.from_keypoints(kt, cam, times))
    ident = match_views(lm, None, kp)
    sources = {v["source"] for v in ident.pairs.values()}
    assert sources == {"keypoints"}
    # each person's tracks: the same 3D person in every view
    assert len(ident.person_ids) == 2
    for pid in ident.person_ids:
        truth = {int(perms[i][t]) for i, c in enumerate(ident.cameras)
                 for t, p in ident.assignments[c].items() if p == pid}
        assert len(truth) == 1
