"""Training HandNet (hands.py) on the body network's crop shards.

    python -m mamma_kit.landmarks.hand_train mamma_kit/landmarks/configs/hands-kp.toml
    python benchmarks/hand_sigma.py runs/hands-kp/hands-kp.pt WORKSPACE... --write

Each training sample is a body crop augmented exactly as the body network's (augment.prepare_sample
at the shard's own resolution: scale, rotation, photometric, occluders, SAM-like mask errors,
keypoint drops), then a hand crop cut from it through the inference contract (hands.hand_inputs)
with a random side (``frac``) and a centre off the true hand centre by about what the body network
misses it by. Samples are made once up front by a process pool (``samples`` of them, each crop seen
several times with different augmentation) and held in memory as uint8, so training steps cost only
the network. The config's [data] val crops are held out: the error reported is the mean visible-landmark
error in % of the box height, after the same cascade inference runs.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import read_toml
from mamma_kit.landmarks import crop as C
from mamma_kit.landmarks import hands as H
from mamma_kit.landmarks.augment import AugmentConfig, prepare_sample
from mamma_kit.landmarks.data import CropShards
from mamma_kit.landmarks.losses import bce, gaussian_nll


@dataclass(frozen=True)
class HandTrainConfig:
    train: tuple[str, ...]
    val: tuple[str, ...]
    out: str = "runs/hands-kp"
    samples: int = 48000
    steps: int = 3000
    batch: int = 64
    lr: float = 2e-3
    weight_decay: float = 1e-4
    frac: tuple[float, float] = (0.22, 0.7)
    centre_jitter: float = 0.2  # sd of the centre's offset, x the crop side
    p_far: float = 0.25  # a centre anywhere within +-0.35 sides instead
    invisible_weight: float = 0.5
    # the tracker's commonest error where people touch (seen on the demo's builtin masks): the other
    # person's arm in the target's mask (p_bleed), or the target's hand in the other's (p_swap)
    p_bleed: float = 0.3
    p_swap: float = 0.15
    seed: int = 0
    threads: int = 2

    @classmethod
    def load(cls, path: Path) -> "HandTrainConfig":
        d = read_toml(path)
        t = dict(d.get("train", {}))
        t = {k: tuple(v) if isinstance(v, list) else v for k, v in t.items()}
        known = {f.name for f in fields(cls)} - {"train", "val"}
        if set(t) - known:
            raise UserError(f"{path}: unknown [train] keys {', '.join(sorted(set(t) - known))}",
                            f"valid keys: {', '.join(sorted(known))}")
        if not d.get("data", {}).get("train") or not d["data"].get("val"):
            raise UserError(f"{path} has no [data] train and val shard folders", "see configs/hands-kp.toml")
        return cls(train=tuple(d["data"]["train"]), val=tuple(d["data"]["val"]), **t)


def hand_sample(sample: dict, ids: tuple[np.ndarray, np.ndarray], cfg: HandTrainConfig, aug: AugmentConfig | None,
                rng: np.random.Generator) -> dict:
    """One training hand crop from one shard sample, of a random side, size and centre: x (10, 64, 64)
    uint8, side, xy_n (60, 2) float32 in the hand crop, visibility and contact (60,)."""
    h, w = sample["images"].shape[:2]
    body = prepare_sample(sample, (w, h), "scale", aug, rng)
    uv = C.normalised_to_crop(body["xy_n"], (w, h))
    side = int(rng.integers(2))
    hid = ids[side]
    size = float(np.ptp(uv, axis=0).max())  # the landmarks' extent: at inference, the mask box's
    frac = math.exp(rng.uniform(*np.log(cfg.frac)))
    s = frac * size
    off = rng.uniform(-0.35, 0.35, 2) * s if rng.random() < cfg.p_far else rng.normal(0, cfg.centre_jitter * s, 2)
    centre_2 = uv[hid].mean(0) + off
    mask, others = body["mask"], body["others"]
    if aug is not None and others.any() and rng.random() < cfg.p_bleed + cfg.p_swap:
        yy, xx = np.mgrid[:h, :w]
        c = uv[hid].mean(0) + rng.normal(0, 0.03 * size, 2)
        disc = (xx - c[0]) ** 2 + (yy - c[1]) ** 2 < (rng.uniform(0.08, 0.35) * size) ** 2
        if rng.random() < cfg.p_bleed / (cfg.p_bleed + cfg.p_swap):
            moved = disc & (others > 0)
            mask, others = np.where(moved, 1, mask).astype(np.uint8), np.where(moved, 0, others).astype(np.uint8)
        else:
            moved = disc & (mask > 0)
            mask, others = np.where(moved, 0, mask).astype(np.uint8), np.where(moved, 1, others).astype(np.uint8)
    kp = None
    if "keypoints" in body:
        k = body["keypoints"].astype(np.float64).copy()
        k[:, :2] = np.where(k[:, 4:5] > 0, C.normalised_to_crop(k[:, :2], (w, h)), np.nan)
        kp = k
    box = H.hand_box(centre_2, size, frac)
    x, M = H.hand_inputs(body["image"], mask, others, kp, side, box)
    xy_h = C.crop_to_normalised(C.apply_affine(M, uv[hid]), (H.HAND_IN, H.HAND_IN))
    return {"x": np.clip(x, 0, 255).astype(np.uint8), "side": np.int64(side), "xy_n": xy_h.astype(np.float32),
            "visibility": body["visibility"][hid].astype(np.float32), "contact": body["contact"][hid].astype(np.float32)}


_POOL: dict = {}


def _init_worker(dirs: tuple[str, ...], cfg: HandTrainConfig) -> None:
    torch.set_num_threads(1)
    shards = CropShards(list(dirs))
    _POOL.update(shards=shards, cfg=cfg, ids=H.hand_landmark_ids(shards.landmark_parts, shards.part_names))


def _make_chunk(args: tuple[int, int, int]) -> dict:
    """``n`` samples of shard ``j`` (one shard per chunk: shards are too big to hop between)."""
    j, n, seed = args
    shards, cfg, ids = _POOL["shards"], _POOL["cfg"], _POOL["ids"]
    aug = AugmentConfig()
    start, count = int(shards.starts[j]), int(shards.counts[j])
    out = []
    for i in range(n):
        rng = np.random.default_rng([seed, j, 0, i])  # 0: the streams the shipped run drew
        out.append(hand_sample(shards[start + int(rng.integers(count))], ids, cfg, aug, rng))
    return {k: np.stack([o[k] for o in out]) for k in out[0]}


def make_samples(cfg: HandTrainConfig) -> dict[str, np.ndarray]:
    """``cfg.samples`` hand samples spread over the shards by their size, made by a process pool."""
    from concurrent.futures import ProcessPoolExecutor

    from mamma_kit.landmarks.data import annotate_keypoints

    annotate_keypoints(list(cfg.train))
    counts = CropShards(list(cfg.train)).counts
    per = np.floor(counts / counts.sum() * cfg.samples).astype(int)
    jobs = [(j, int(c), cfg.seed) for j, c in enumerate(per) if c > 0]
    parts = []
    with ProcessPoolExecutor(cfg.threads, initializer=_init_worker, initargs=(cfg.train, cfg)) as ex, \
            log.progress("hand samples", len(jobs)) as advance:
        for part in ex.map(_make_chunk, jobs):
            parts.append(part)
            advance(1)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def hand_loss(out: dict, xy_n: torch.Tensor, vis: torch.Tensor, invisible_weight: float,
              contact: torch.Tensor | None = None) -> tuple[torch.Tensor, dict]:
    """Gaussian NLL of the positions (visible landmarks weigh 1, hidden ``invisible_weight``, those
    outside the crop 0.3 of that), visibility BCE and, with ``contact``, contact BCE (positives x 4:
    they are rare)."""
    nll = gaussian_nll(out["xy"], out["log_sigma"], xy_n)
    inside = (xy_n.abs() <= 1.2).all(-1).float()
    w = (vis + invisible_weight * (1 - vis)) * (0.3 + 0.7 * inside)
    l_xy = (nll * w).sum() / w.sum()
    l_vis = bce(out["vis_logit"], vis).mean()
    parts = {"nll": l_xy.item(), "vis": l_vis.item()}
    loss = l_xy + l_vis
    if contact is not None:
        l_con = torch.nn.functional.binary_cross_entropy_with_logits(out["contact_logit"], contact,
                                                                     pos_weight=torch.tensor(4.0))
        parts["contact"] = l_con.item()
        loss = loss + l_con
    return loss, parts


def evaluate(refiner: H.HandRefiner, dirs: tuple[str, ...], body_pred=None, limit: int = 300) -> dict:
    """Held-out crops: the cascade from the true hand centre jittered as in training (or from the
    body network's hand centroid with ``body_pred``, a landmarks.inference.Predictor), against the
    truth. Mean visible-landmark error in % of the box height: the refined landmarks', and the body
    network's with ``body_pred`` or else the jittered start's."""
    shards = CropShards(list(dirs))
    ids = refiner.ids
    rng = np.random.default_rng(123)
    errs, body_errs, start_errs = [], [], []
    for i in range(min(limit, len(shards))):
        s = shards[i]
        h, w = s["images"].shape[:2]
        uv = s["xy"].astype(np.float64)
        box = C.mask_box(s["instance"] == 1)
        if box is None:
            continue
        size = H.person_size(box)
        bh = box[3] - box[1]
        others = s["instance"] >= 2
        kp = s.get("keypoints")
        kp = None if kp is None else np.where(kp[:, 4:5] > 0, kp, np.nan).astype(np.float64)
        body_xy = None
        if body_pred is not None:  # every person of the crop, the target first (the others' mask)
            masks = [s["instance"] == v for v in [1] + sorted(set(np.unique(s["instance"]).tolist()) - {0, 1})]
            body_out = body_pred.predict_image(s["images"], masks, [kp] + [None] * (len(masks) - 1))
            body_xy, body_sig = body_out["xy"][0], body_out["sigma"][0]
        for side in (0, 1):
            hid = ids[side]
            vis = s["visibility"][hid] > 0
            if vis.sum() < 5:
                continue
            if body_xy is not None:
                start, start_sig = body_xy.copy(), body_sig.copy()
                body_errs.append(np.linalg.norm(body_xy[hid] - uv[hid], axis=1)[vis].mean() / bh * 100)
            else:
                start, start_sig = np.full_like(uv, np.nan), np.full_like(uv, 1e6)  # no prior: HandNet alone
                start[hid] = uv[hid] + rng.normal(0, 0.05 * size, 2)
                start_errs.append(np.linalg.norm(start[hid] - uv[hid], axis=1)[vis].mean() / bh * 100)
            person = {"image": s["images"], "xy": start.copy(), "sigma": start_sig, "tight_box": box,
                      "mask": s["instance"] == 1, "others": others, "keypoints": kp}
            refiner.refine([person], side)
            e = np.linalg.norm(person["xy"][hid] - uv[hid], axis=1)
            errs.append(e[vis].mean() / bh * 100)
    out = {"hands": len(errs), "visible_error_pct": float(np.mean(errs))}
    if body_errs:
        out["body_network_visible_error_pct"] = float(np.mean(body_errs))
    if start_errs:
        out["start_visible_error_pct"] = float(np.mean(start_errs))
    return out


def train(cfg: HandTrainConfig) -> Path:
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    data = make_samples(cfg)
    log.info(f"{len(data['x'])} hand samples in {time.perf_counter() - t0:.0f} s")
    shards = CropShards(list(cfg.train))
    model = H.HandNet()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    warm = max(1, cfg.steps // 20)  # linear warm-up, then cosine to zero
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda k: min(1.0, (k + 1) / warm) * 0.5 * (1 + math.cos(math.pi * min(k, cfg.steps) / cfg.steps)))
    rng = np.random.default_rng(cfg.seed)
    n = len(data["x"])
    t1 = time.perf_counter()
    model.train()
    with log.progress("hand network", cfg.steps) as advance:
        for step in range(cfg.steps):
            idx = rng.integers(0, n, cfg.batch)
            x = torch.as_tensor(data["x"][idx]).float()
            res = model(x, torch.as_tensor(data["side"][idx]))
            loss, parts = hand_loss(res, torch.as_tensor(data["xy_n"][idx]), torch.as_tensor(data["visibility"][idx]),
                                    cfg.invisible_weight, torch.as_tensor(data["contact"][idx]))
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            sched.step()
            if step % 100 == 0:
                log.info(f"step {step}: loss {loss.item():.3f} " + " ".join(f"{k} {v:.3f}" for k, v in parts.items()))
            advance(1)
    model.eval()
    loaded = H.LoadedHands(model, shards.landmark_set, "", {})
    refiner = H.HandRefiner(loaded, shards.landmark_parts, shards.part_names)
    val = evaluate(refiner, cfg.val)
    log.info(f"held out: {val}")
    card = {"train": list(cfg.train), "val": list(cfg.val), "samples": n, "steps": cfg.steps, "batch": cfg.batch,
            "seconds_samples": round(t1 - t0, 1), "seconds_train": round(time.perf_counter() - t1, 1), "held_out": val}
    return H.save_hand_weights(out / "hands-kp.pt", model, shards.landmark_set, card)


def main() -> None:
    ap = argparse.ArgumentParser(description="Train HandNet (mamma_kit.landmarks.hands) from crop shards "
                                             "(then benchmarks/hand_sigma.py calibrates its sigma).")
    ap.add_argument("config", type=Path, help="training config (.toml)")
    ap.add_argument("--steps", type=int, default=None, help="override [train] steps")
    ap.add_argument("--samples", type=int, default=None, help="override [train] samples")
    a = ap.parse_args()
    cfg = HandTrainConfig.load(a.config)
    over = {k: v for k, v in (("steps", a.steps), ("samples", a.samples)) if v is not None}
    if over:
        cfg = HandTrainConfig(**{**cfg.__dict__, **over})
    print(train(cfg))


if __name__ == "__main__":
    main()
