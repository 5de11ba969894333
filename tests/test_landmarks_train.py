"""Crop shards, augmentation and `mamma-kit train` on toy crops whose landmark positions are known."""

import json

import cv2
import numpy as np
import pytest
import torch

from mamma_kit.landmarks.augment import AugmentConfig, prepare_sample
from mamma_kit.landmarks.data import CropShards, write_crop_shards

L = 16
PART_NAMES = ["body", "left_hand", "right_hand", "head", "left_foot", "right_foot"]
# a stick figure in a unit box (x right, y down): head, neck, shoulders, elbows, hands, hips, knees, feet, belly
TEMPLATE = np.array([[0.5, 0.06], [0.5, 0.18], [0.3, 0.22], [0.7, 0.22], [0.2, 0.4], [0.8, 0.4], [0.15, 0.55],
                     [0.85, 0.55], [0.38, 0.55], [0.62, 0.55], [0.36, 0.76], [0.64, 0.76], [0.34, 0.97], [0.66, 0.97],
                     [0.5, 0.35], [0.5, 0.12]])
PARTS = np.array([3, 0, 0, 0, 0, 0, 1, 2, 0, 0, 0, 0, 4, 5, 0, 3])
PALETTE = (np.stack(np.meshgrid([40, 140, 240], [40, 140, 240], [40, 240]), -1).reshape(-1, 3)[:L]).astype(np.uint8)


def toy_crops(n, seed, hw=(80, 60)):
    """Toy shard samples: a stick figure (instance 1) with one coloured disc per visible landmark,
    sometimes a second figure (instance 2); contact = landmarks near the other figure, floor contact =
    feet of figures standing on a drawn floor line."""
    H, W = hw
    rng = np.random.default_rng(seed)
    out = {k: [] for k in ("images", "instance", "xy", "visibility", "contact", "floor_contact", "box")}
    for _ in range(n):
        img = np.clip(rng.normal(rng.uniform(60, 200, 3), 12, (H, W, 3)), 0, 255).astype(np.uint8)
        inst = np.zeros((H, W), np.uint8)

        def figure(cx, cy, h, ang):
            c, s = np.cos(ang), np.sin(ang)
            p = (TEMPLATE - 0.5) * [0.6 * h, h]
            return np.stack([c * p[:, 0] - s * p[:, 1] + cx, s * p[:, 0] + c * p[:, 1] + cy], 1)

        h = rng.uniform(38, 52)
        xy = figure(W / 2 + rng.uniform(-5, 5), H / 2 + rng.uniform(-4, 4), h, rng.uniform(-0.3, 0.3))
        other = None
        if rng.random() < 0.5:
            other = figure(W / 2 + rng.choice([-1, 1]) * rng.uniform(14, 22), H / 2 + rng.uniform(-4, 4), h, 0.0)
            cv2.fillConvexPoly(inst, cv2.convexHull(other.astype(np.int32)), 2)
            cv2.fillConvexPoly(img, cv2.convexHull(other.astype(np.int32)), (90, 90, 90))
        hull = np.zeros((H, W), np.uint8)
        cv2.fillConvexPoly(hull, cv2.convexHull(np.round(xy).astype(np.int32)), 1)
        inst[hull > 0] = 1
        img[hull > 0] = (img[hull > 0] * 0.3 + np.array([200, 180, 160]) * 0.7).astype(np.uint8)
        standing = rng.random() < 0.5
        if standing:
            cv2.line(img, (0, int(xy[12:14, 1].max()) + 2), (W - 1, int(xy[12:14, 1].max()) + 2), (30, 30, 30), 2)
        vis = (rng.random(L) > 0.2).astype(np.uint8)
        for i in np.flatnonzero(vis):  # 16 discs per toy image
            cv2.circle(img, tuple(int(round(v)) for v in xy[i]), 2, tuple(int(c) for c in PALETTE[i]), -1)
        contact = np.zeros(L, np.uint8)
        if other is not None:
            d = np.linalg.norm(xy[:, None] - other[None], axis=-1).min(1)
            contact = (d < 8).astype(np.uint8)
        floor = np.zeros(L, np.uint8)
        floor[[12, 13]] = standing
        ys, xs = np.nonzero(inst == 1)
        out["images"].append(img)
        out["instance"].append(inst)
        out["xy"].append(xy.astype(np.float32))
        out["visibility"].append(vis)
        out["contact"].append(contact)
        out["floor_contact"].append(floor)
        out["box"].append(np.array([xs.min(), ys.min(), xs.max(), ys.max()], np.float32))
    return {k: np.stack(v) for k, v in out.items()}


def write_toy_shards(d, n, seed, shard_size=24):
    meta = {"landmark_set": "toy-16", "recipes": ["toy"], "seeds": [seed], "landmark_parts": PARTS.tolist(),
            "landmark_part_names": PART_NAMES}
    return write_crop_shards(d, toy_crops(n, seed), meta, shard_size)


def test_shard_loader_and_deterministic_order(tmp_path):
    write_toy_shards(tmp_path / "a", 64, seed=1)
    s = CropShards(tmp_path / "a")
    assert len(s) == 64 and len(s.shards) == 3 and s.n_landmarks == L and s.crop_hw == (80, 60)
    assert s.landmark_set == "toy-16" and s.part_names == PART_NAMES and np.array_equal(s.landmark_parts, PARTS)
    epoch = np.concatenate([s.batch_indices(7, st, 8) for st in range(8)])
    assert sorted(epoch.tolist()) == list(range(64))  # every sample once per epoch
    assert np.array_equal(s.batch_indices(7, 3, 8), s.batch_indices(7, 3, 8))
    assert not np.array_equal(s.batch_indices(7, 8, 8), epoch[:8])  # next epoch reshuffles
    shard_of = np.array([s.locate(int(i))[0] for i in epoch])
    assert (np.diff(shard_of) != 0).sum() == 2  # shards are visited one after another
    a = s[int(epoch[0])]
    assert a["images"].shape == (80, 60, 3) and a["xy"].shape == (L, 2)
    assert s.describe()["seeds"] == ["1"]


def test_augmented_labels_follow_the_pixels(tmp_path):
    samples = toy_crops(12, seed=2)
    aug = AugmentConfig(scale=(0.8, 1.3), translate=0.1, p_rotate=1.0, max_rotate_deg=30, p_part_crop=0.3,
                        p_photometric=0.0, p_blur=0, p_noise=0, p_jpeg=0, p_downup=0, p_occluder=0, p_mask_corrupt=0,
                        p_no_mask=0)
    checked = 0
    for i in range(12):
        one = {k: v[i] for k, v in samples.items()}
        r = prepare_sample(one, (48, 64), "scale", aug, np.random.default_rng(i))
        uv = (r["xy_n"] + 1) / 2 * [48, 64] - 0.5
        ok = (r["visibility"] > 0) & (uv[:, 0] > 1) & (uv[:, 0] < 46) & (uv[:, 1] > 1) & (uv[:, 1] < 62)
        px = r["image"][np.round(uv[ok, 1]).astype(int), np.round(uv[ok, 0]).astype(int)].astype(int)
        # the disc of landmark j is found at its label (colours are 100 apart; allow interpolation at the rim)
        assert np.abs(px - PALETTE[ok].astype(int)).max(1).mean() < 35
        checked += ok.sum()
        # the mask is the target's instance, warped by the same affine
        assert r["mask"].sum() > 0
    assert checked > 100


def test_mask_corruption_and_no_mask(tmp_path):
    samples = toy_crops(10, seed=3)
    exact = AugmentConfig.none()
    bad = AugmentConfig(p_photometric=0, p_blur=0, p_noise=0, p_jpeg=0, p_downup=0, p_occluder=0, p_mask_corrupt=1.0,
                        p_no_mask=0, p_rotate=0, p_part_crop=0, scale=(1, 1), translate=0)
    ious = []
    for i in range(10):
        one = {k: v[i] for k, v in samples.items()}
        a = prepare_sample(one, (48, 64), "scale", exact, np.random.default_rng(i))["mask"] > 0
        b = prepare_sample(one, (48, 64), "scale", bad, np.random.default_rng(i))["mask"] > 0
        ious.append((a & b).sum() / max((a | b).sum(), 1))
    assert min(ious) > 0.2 and np.mean(ious) < 0.97  # corrupted, but still about the person
    none = AugmentConfig(**{**bad.__dict__, "p_no_mask": 1.0})
    assert prepare_sample({k: v[0] for k, v in samples.items()}, (48, 64), "scale", none,
                          np.random.default_rng(0))["mask"].sum() == 0
    occl = AugmentConfig(**{**exact.__dict__, "p_occluder": 1.0})
    lost = [(s["visibility"] > 0).sum() - (prepare_sample(s, (48, 64), "scale", occl, np.random.default_rng(i))
                                           ["visibility"] > 0).sum()
            for i, s in enumerate({k: v[j] for k, v in samples.items()} for j in range(10))]
    assert min(lost) >= 0 and sum(lost) > 0  # occluders hide landmarks, never reveal them


def _config(tmp_path, out, steps=40):
    cfg = tmp_path / "train.toml"
    cfg.write_text(f"""
[model]
arch = "tiny"
[data]
train = ["{tmp_path / 'train'}"]
val = ["{tmp_path / 'val'}"]
[train]
out = "{out}"
steps = {steps}
batch = 8
lr = 3e-3
warmup = 5
log_every = 5
ckpt_every = 10
eval_every = 20
eval_samples = 16
threads = 1
[augment]
p_jpeg = 0.0
""")
    return cfg


def test_train_loss_drops_and_resume_continues(tmp_path, cli):
    write_toy_shards(tmp_path / "train", 48, seed=10)
    write_toy_shards(tmp_path / "val", 16, seed=99)
    cfg = _config(tmp_path, tmp_path / "run")
    res = cli("train", cfg, "--for-steps", "20", "--json", "--quiet")  # a slice, as if interrupted
    assert res.code == 0, res
    assert json.loads(res.out) == {"paused": True, "steps": 20, "of": 40, "checkpoint": str(tmp_path / "run" /
                                   "checkpoint.pt"), "out": str(tmp_path / "run")}
    assert not (tmp_path / "run" / "tiny.pt").exists()
    # a second start without --resume refuses to overwrite the run
    res2 = cli("train", cfg, "--quiet")
    assert res2.code == 2 and "--resume" in res2.err
    # a checkpoint written before a config field existed resumes with the field's default
    ck = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    del ck["model_config"]["layout_visibility"]
    torch.save(ck, tmp_path / "run" / "checkpoint.pt")
    res = cli("train", cfg, "--resume", "--json", "--quiet")
    assert res.code == 0, res
    summary = json.loads(res.out)
    assert summary["steps"] == 40
    log = [json.loads(x) for x in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == list(range(5, 45, 5))  # resumed at 20, no step twice
    first, last = np.mean([r["loss"] for r in log[:2]]), np.mean([r["loss"] for r in log[-2:]])
    assert last < 0.7 * first, (first, last)
    # resuming replays exactly what an uninterrupted run does
    res = cli("train", _config(tmp_path, tmp_path / "straight"), "--quiet")
    assert res.code == 0, res
    a = torch.load(tmp_path / "run" / "tiny.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "straight" / "tiny.pt", weights_only=True)["state_dict"]
    assert all(torch.allclose(a[k], b[k], atol=1e-5) for k in a)
    # the model card describes data, steps and held-out metrics, next to the weights
    card = json.loads((tmp_path / "run" / "model_card.json").read_text())
    assert card["training"]["steps"] == 40 and card["data"]["train"]["samples"] == 48
    assert card["data"]["val"]["seeds"] == ["99"] and card["metrics"]["error_px_visible"] is not None
    assert "Held-out metrics" in (tmp_path / "run" / "model_card.md").read_text()
    from mamma_kit.landmarks.weights import load_model

    loaded = load_model(tmp_path / "run" / "tiny.pt")
    assert loaded.landmark_set == "toy-16" and loaded.config.n_landmarks == L
    # the layout visibility head: fitted on the run's crops, shipped in the weights, used by forward
    res = cli("train", cfg, "--out", tmp_path / "run", "--export", "--layout-visibility", "--json", "--quiet")
    assert res.code == 0, res
    lm = load_model(tmp_path / "run" / "tiny.pt")
    assert lm.config.layout_visibility and lm.model.layout_vis is not None
    card = json.loads((tmp_path / "run" / "model_card.json").read_text())
    assert card["training"]["layout_visibility"]["predicted_crops"] == 48
    assert "intermediate" not in card["training"] and "layout head" in (tmp_path / "run" / "model_card.md").read_text()
    H, W = lm.config.input_hw
    with torch.no_grad():
        out = lm.model(torch.zeros(2, 3, H, W), torch.ones(2, 1, H, W))
        xy_px = out["xy"] * torch.tensor([W / 2, H / 2])
        assert torch.allclose(out["vis_logit"], lm.model.layout_vis(xy_px), atol=1e-5)
    assert cli("train", cfg, "--layout-visibility", "--quiet").code == 2


def test_train_config_errors(tmp_path, cli):
    bad = tmp_path / "bad.toml"
    bad.write_text('[model]\narch = "tiny"\n[data]\ntrain = ["nowhere"]\n[train]\nsteps = 2\nfoo = 1\n')
    res = cli("train", bad)
    assert res.code == 2 and "foo" in res.err
    bad.write_text('[model]\narch = "tiny"\n[data]\ntrain = ["nowhere"]\n')
    res = cli("train", bad)
    assert res.code == 2 and "nowhere" in res.err


@pytest.mark.parametrize("name", ["embedded", "embedded-single", "embedded-kp"])
def test_committed_training_configs_parse(name):
    from pathlib import Path

    from mamma_kit.landmarks.train import load_train_config

    p = Path(__file__).resolve().parents[1] / "mamma_kit" / "landmarks" / "configs" / f"{name}.toml"
    tc = load_train_config(p)
    assert tc.model.name == name and tc.val_dirs
    # the keypoint-guided model's schedule is short: its keypoint prior is trained first
    assert tc.settings.steps > 1000 or (tc.model.keypoints_in and tc.settings.prior_steps >= 1000)
