"""`mamma-kit train CONFIG`: train a MammaNet on crop shards, resumable, with a model card.

Training config (TOML; paths relative to the current directory unless absolute)::

    [model]
    arch = "embedded"            # a named config (landmarks/config.py) ...
    # dim = 160                  # ... with any MammaNetConfig field overridden
    [data]
    train = ["data/crops/train"] # shard folders (`mamma-kit synth RECIPE --crops N --out DIR`)
    val = ["data/crops/val"]     # held-out recipes / seeds (optional)
    [train]
    out = "runs/embedded"        # checkpoint.pt, <arch>.pt, model_card.{md,json}, log.jsonl
    steps = 30000
    batch = 16
    lr = 3e-4
    weight_decay = 1e-4
    warmup = 500                 # linear warm-up steps
    schedule = "cosine"          # or "step": x0.1 at each of `milestones`
    milestones = []
    grad_clip = 1.0
    seed = 0
    threads = 0                  # torch threads (0 = torch's default)
    log_every = 50
    ckpt_every = 500
    eval_every = 2000
    eval_samples = 512
    half_weights = false         # store the final weights as float16 (halves the file)
    [loss]                       # LossWeights: xy = 100, visibility = 1, contact = 1, floor_contact = 1, ...
    [augment]                    # AugmentConfig fields (augment.py)

Every batch is a pure function of (seed, step): shards are visited in a seeded order and each sample's
augmentation draws from its own generator, so ``--resume`` continues exactly where the checkpoint
(written atomically every ``ckpt_every`` steps and on Ctrl-C) stopped.
"""

from __future__ import annotations

import json
import math
import platform
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import torch

from mamma_kit import __version__
from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.io import atomic_path, atomic_write_text, read_toml, sha256_file, write_json
from mamma_kit.landmarks import crop as C
from mamma_kit.landmarks.augment import AugmentConfig
from mamma_kit.landmarks.batches import batch_to_torch, make_batch, run_model
from mamma_kit.landmarks.config import MammaNetConfig, get_config
from mamma_kit.landmarks.data import CropShards
from mamma_kit.landmarks.losses import DOUBLED_PARTS, LossWeights, mammanet_loss
from mamma_kit.landmarks.metrics import landmark_metrics
from mamma_kit.landmarks.model import MammaNet, count_parameters
from mamma_kit.landmarks.prefetch import threaded
from mamma_kit.landmarks.weights import save_weights

CHECKPOINT_FORMAT = "mamma-kit/mammanet-train/1"


@dataclass
class TrainSettings:
    out: str = "runs/mammanet"
    steps: int = 1000
    batch: int = 16
    lr: float = 3e-4
    weight_decay: float = 1e-4
    warmup: int = 500
    schedule: str = "cosine"
    milestones: list[int] = field(default_factory=list)
    grad_clip: float = 1.0
    seed: int = 0
    threads: int = 0
    log_every: int = 50
    ckpt_every: int = 500
    eval_every: int = 2000
    eval_samples: int = 512
    half_weights: bool = False
    init_from: str = ""  # a training checkpoint or weight file whose matching tensors start a new run
    prior_steps: int = 0  # keypoint-guided models: steps of the keypoint prior alone before the network
    # trains (then the prior is frozen)
    prior_batch: int = 256


@dataclass
class TrainConfig:
    path: Path
    model: MammaNetConfig
    model_explicit_landmarks: bool
    train_dirs: list[Path]
    val_dirs: list[Path]
    settings: TrainSettings
    loss: LossWeights
    augment: AugmentConfig
    raw: dict

    def describe(self) -> dict:
        return {"config_file": str(self.path), "model": self.model.to_dict(), "train": asdict(self.settings),
                "loss": asdict(self.loss), "augment": {k: list(v) if isinstance(v, tuple) else v
                                                       for k, v in asdict(self.augment).items()},
                "data": {"train": [str(p) for p in self.train_dirs], "val": [str(p) for p in self.val_dirs]}}


def _fields(cls, d: dict, section: str) -> dict:
    known = {f.name for f in fields(cls)}
    bad = sorted(set(d) - known)
    if bad:
        raise UserError(f"unknown keys in [{section}]: {', '.join(bad)}", f"valid keys: {', '.join(sorted(known))}")
    return d


def load_train_config(path: str | Path, out: str | None = None, steps: int | None = None) -> TrainConfig:
    p = Path(path)
    raw = read_toml(p, "training config")
    model = dict(raw.get("model", {}))
    arch = model.pop("arch", "embedded")
    explicit_lm = "n_landmarks" in model
    cfg = get_config(arch, **model)
    data = raw.get("data", {})
    train_dirs = [Path(d) for d in _list(data.get("train"))]
    if not train_dirs:
        raise UserError(f"{p} lists no training shards", "add [data] train = [\"DIR\", ...]")
    s = TrainSettings(**_fields(TrainSettings, dict(raw.get("train", {})), "train"))
    if out is not None:
        s.out = out
    if steps is not None:
        s.steps = int(steps)
    if s.schedule not in ("cosine", "step"):
        raise UserError(f"[train] schedule '{s.schedule}' is unknown", "use \"cosine\" or \"step\"")
    loss = LossWeights(**_fields(LossWeights, dict(raw.get("loss", {})), "loss"))
    aug = AugmentConfig.from_dict(dict(raw.get("augment", {})))
    return TrainConfig(p, cfg, explicit_lm, train_dirs, [Path(d) for d in _list(data.get("val"))], s, loss, aug, raw)


def _list(v) -> list:
    if v is None:
        return []
    return [v] if isinstance(v, str) else list(v)


def lr_at(step: int, s: TrainSettings) -> float:
    if s.warmup and step < s.warmup:
        return s.lr * (step + 1) / s.warmup
    if s.schedule == "step":
        return s.lr * 0.1 ** sum(step >= m for m in s.milestones)
    span = max(1, s.steps - s.warmup)
    return s.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(1.0, (step - s.warmup) / span))))


def _param_groups(model: MammaNet, wd: float) -> list[dict]:
    decay, no_decay = [], []
    for name, p in model.named_parameters():
        (decay if p.ndim >= 2 and "pos_embed" not in name and "query_embed" not in name else no_decay).append(p)
    return [{"params": decay, "weight_decay": wd}, {"params": no_decay, "weight_decay": 0.0}]


def _ensure_keypoints(cfg: MammaNetConfig, dirs: list[Path]) -> None:
    """A keypoint-guided model reads the keypoint model's points of every crop: run it once on the
    shards that have none yet (keypoints_NNNN.npz beside them; later runs reuse them)."""
    if cfg.keypoints_in:
        from mamma_kit.landmarks.data import annotate_keypoints

        annotate_keypoints(dirs)


@torch.inference_mode()
def evaluate_crops(model: MammaNet, shards: CropShards, n: int, batch: int = 16, device: str = "cpu",
                   seed: int = 12345) -> dict:
    """Metrics on up to ``n`` held-out crops (no augmentation, exact masks), errors in input-crop px."""
    model.eval()
    cfg = model.cfg
    H, W = cfg.input_hw
    idx = np.sort(np.random.default_rng(seed).permutation(len(shards))[:n])  # sorted: shard by shard
    acc: dict[str, list] = {k: [] for k in ("xy_p", "xy_g", "box_h", "vis_g", "vis_p", "con_g", "con_p", "flo_g", "flo_p")}
    for a in range(0, len(idx), batch):
        b = make_batch(shards, idx[a:a + batch], cfg, None, (seed, a))
        out = run_model(model, batch_to_torch(b, device))
        acc["xy_p"].append(C.normalised_to_crop(out["xy"].float().cpu().numpy(), (W, H)))
        acc["xy_g"].append(C.normalised_to_crop(b["xy_n"], (W, H)))
        acc["box_h"].append(b["box_h"])
        acc["vis_g"].append(b["visibility"])
        acc["vis_p"].append(torch.sigmoid(out["vis_logit"]).float().cpu().numpy())
        acc["con_g"].append(b["contact"])
        acc["con_p"].append(torch.sigmoid(out["contact_logit"]).float().cpu().numpy())
        acc["flo_g"].append(b["floor_contact"])
        acc["flo_p"].append(torch.sigmoid(out["floor_logit"]).float().cpu().numpy())
    cat = {k: np.concatenate(v) for k, v in acc.items()}
    m = landmark_metrics(cat["xy_p"], cat["xy_g"], cat["box_h"], cat["vis_g"], cat["vis_p"], cat["con_g"], cat["con_p"],
                         cat["flo_g"], cat["flo_p"])
    m["crop_px"] = [W, H]
    return m


def warm_start(model: MammaNet, src: Path) -> dict:
    """Copy every tensor of ``src`` (a training checkpoint or a weight file) whose name and shape
    match into ``model``; the rest keep their fresh initialisation. A model that gains a dense
    head starts its decoder's position outputs at zero (they become offsets to the dense head)."""
    if not src.is_file():
        raise UserError(f"[train] init_from {src} not found", "point it at a checkpoint.pt or a weights .pt")
    obj = torch.load(src, map_location="cpu", weights_only=True)
    sd = obj.get("model") or obj.get("state_dict") or obj
    own = model.state_dict()
    same = {k: v.float() for k, v in sd.items() if k in own and tuple(v.shape) == tuple(own[k].shape)}
    model.load_state_dict(same, strict=False)
    src_cfg = obj.get("model_config") or obj.get("config") or {}
    if model.cfg.dense_head and not src_cfg.get("dense_head", False):
        with torch.no_grad():
            last = model.decoder.landmarks.layers[-1]
            last.weight.view(-1, 3, last.weight.shape[-1])[:, :2] = 0
            last.bias.view(-1, 3)[:, :2] = 0
    info = {"source": str(src), "tensors_copied": len(same), "tensors_new": sorted(set(own) - set(same))}
    log.info(f"warm start from {src}: {len(same)} of {len(own)} tensors copied")
    return info


def prior_pairs(shards: CropShards, cfg: MammaNetConfig, seed: int = 0) -> dict[str, torch.Tensor]:
    """Every crop's (keypoints (N, P, 5), landmarks xy_n (N, L, 2), per-landmark weights (N, L)) in
    the network's crop (no augmentation): the keypoint prior's training set."""
    from mamma_kit.landmarks.losses import landmark_weights

    keys = ("keypoints", "xy_n", "visibility", "floor_contact")
    parts: dict[str, list] = {k: [] for k in keys}
    for a in range(0, len(shards), 256):
        b = make_batch(shards, np.arange(a, min(len(shards), a + 256)), cfg, None, (seed, a))
        for k in keys:
            parts[k].append(b[k])
    out = {k: torch.as_tensor(np.concatenate(v)) for k, v in parts.items()}
    out["weight"] = landmark_weights(out["xy_n"])
    return out


def pretrain_prior(model: MammaNet, pairs: dict[str, torch.Tensor], steps: int, batch: int = 256, lr: float = 2e-3,
                   seed: int = 0, aug: AugmentConfig | None = None) -> dict:
    """Train the keypoint prior alone (an MLP on points: thousands of steps a minute on a CPU) on
    (points, landmarks) pairs under random rotations about the points' centre and the augmentation's
    point drops and jitter; the network's training then starts from a prior that already places the
    landmarks. Returns the L1 (normalised units) before and after."""
    from mamma_kit.landmarks.losses import prior_loss as prior_term
    from mamma_kit.landmarks.model import keypoint_frame

    aug = aug or AugmentConfig()
    g = torch.Generator().manual_seed(seed)
    opt = torch.optim.AdamW(model.prior.parameters(), lr=lr, weight_decay=1e-4)
    kp_all, xy_all, w_all = pairs["keypoints"], pairs["xy_n"], pairs["weight"]
    N = len(kp_all)

    def prior_loss(kp, xy, idx):
        p = model.prior(kp)
        out = {"xy_prior": p["xy"], "vis_logit_prior": p["vis_logit"], "floor_logit_prior": p["floor_logit"]}
        b = {"xy_n": xy, "visibility": pairs["visibility"][idx], "floor_contact": pairs["floor_contact"][idx]}
        return prior_term(out, b, w_all[idx])

    def l1(kp, xy, w):
        return ((model.prior(kp)["xy"] - xy).abs().sum(-1) * w).sum() / w.sum().clamp_min(1e-6)

    with torch.no_grad():
        before = float(l1(kp_all[:2048], xy_all[:2048], w_all[:2048]))
    t0 = time.perf_counter()
    for st in range(steps):
        for gr in opt.param_groups:
            gr["lr"] = lr * 0.5 * (1 + math.cos(math.pi * st / max(1, steps)))
        idx = torch.randint(0, N, (batch,), generator=g)
        kp, xy, w = kp_all[idx].clone(), xy_all[idx].clone(), w_all[idx]
        c, _ = keypoint_frame(kp)
        ang = (torch.rand(batch, generator=g) - 0.5) * 2 * math.radians(aug.max_rotate_deg) * \
            (torch.rand(batch, generator=g) < aug.p_rotate)
        R = torch.stack([torch.cos(ang), -torch.sin(ang), torch.sin(ang), torch.cos(ang)], -1).reshape(-1, 1, 2, 2)
        present = kp[..., 4:5] > 0
        kp[..., :2] = torch.where(present, c + ((kp[..., :2] - c)[..., None, :] @ R.transpose(-1, -2))[..., 0, :],
                                  kp[..., :2])
        xy = c + ((xy - c)[..., None, :] @ R.transpose(-1, -2))[..., 0, :]
        drop = (torch.rand(kp.shape[:2], generator=g) < aug.p_kp_drop_point)[..., None] | \
            (torch.rand(batch, 1, 1, generator=g) < aug.p_kp_missing)
        kp = torch.where(drop, torch.zeros_like(kp), kp)
        kp[..., :2] = kp[..., :2] + aug.kp_jitter * torch.randn(kp[..., :2].shape, generator=g) * (kp[..., 4:5] > 0)
        loss = prior_loss(kp, xy, idx)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    with torch.no_grad():
        after = float(l1(kp_all[:2048], xy_all[:2048], w_all[:2048]))
    info = {"steps": steps, "batch": batch, "pairs": N, "l1_before": round(before, 4), "l1_after": round(after, 4),
            "seconds": round(time.perf_counter() - t0, 1)}
    log.info(f"keypoint prior: {steps} steps on {N} crops in {info['seconds']} s, L1 {before:.3f} -> {after:.3f}")
    return info


def _save_checkpoint(path: Path, model, opt, step: int, tc: TrainConfig, state: dict) -> None:
    obj = {"format": CHECKPOINT_FORMAT, "step": step, "model_config": tc.model.to_dict(),
           "model": model.state_dict(), "optimizer": opt.state_dict(), "state": json.dumps(state)}
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def _doubled_ids(shards: CropShards) -> list[int]:
    return [i for i, n in enumerate(shards.part_names) if n in DOUBLED_PARTS] if shards.landmark_parts is not None else []


def train(config_path: str | Path, resume: bool = False, device: str = "cpu", out: str | None = None,
          steps: int | None = None, for_steps: int | None = None, for_minutes: float | None = None) -> dict:
    """Run (or resume) a training; returns a summary (also written to the model card).

    ``for_steps`` / ``for_minutes`` end this run early with a checkpoint (a slice of a long training on
    a shared machine); ``--resume`` continues it. Weights and model card are written when ``steps`` is reached.
    """
    tc = load_train_config(config_path, out, steps)
    s = tc.settings
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise UserError("--device cuda but torch sees no CUDA device", "use --device cpu")
    if s.threads:
        torch.set_num_threads(s.threads)
    _ensure_keypoints(tc.model, tc.train_dirs + tc.val_dirs)
    train_set = CropShards(tc.train_dirs)
    val_set = CropShards(tc.val_dirs) if tc.val_dirs else None
    cfg = tc.model
    if cfg.n_landmarks != train_set.n_landmarks:
        if tc.model_explicit_landmarks:
            raise UserError(f"the model has {cfg.n_landmarks} landmarks, the shards {train_set.n_landmarks}",
                            "set [model] n_landmarks to the shards' count or drop it")
        cfg = MammaNetConfig.from_dict({**cfg.to_dict(), "n_landmarks": train_set.n_landmarks})
        tc.model = cfg
    if val_set is not None and val_set.n_landmarks != cfg.n_landmarks:
        raise UserError("validation shards have another landmark count than the training shards",
                        "use crops of one landmark set")
    out_dir = Path(s.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    ckpt_path = out_dir / "checkpoint.pt"
    torch.manual_seed(s.seed)
    model = MammaNet(cfg).to(device)
    opt = torch.optim.AdamW(_param_groups(model, s.weight_decay), lr=s.lr, betas=(0.9, 0.999))
    step, state = 0, {"seconds": 0.0, "history": [], "evals": []}
    if ckpt_path.exists():
        if not resume:
            raise UserError(f"{ckpt_path} already holds a training run",
                            "pass --resume to continue it, or choose another [train] out / --out")
        ck = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        if ck.get("format") != CHECKPOINT_FORMAT:
            raise UserError(f"{ckpt_path} is not a mamma-kit training checkpoint", "choose another output folder")
        # through from_dict: a checkpoint written before a config field existed gets its default
        if MammaNetConfig.from_dict(ck["model_config"]) != cfg:
            raise UserError(f"{ckpt_path} was trained with another model config", "resume with the same [model] section")
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        step, state = int(ck["step"]), json.loads(ck["state"])
        log.info(f"resuming {ckpt_path} at step {step}")
    elif resume:
        log.info(f"no checkpoint in {out_dir}: starting a new run")
    if step == 0 and s.init_from:
        state["init_from"] = warm_start(model, Path(s.init_from))
    if step == 0 and s.prior_steps and model.prior is not None:
        state["prior_pretraining"] = pretrain_prior(model, prior_pairs(train_set, cfg, s.seed), s.prior_steps,
                                                    s.prior_batch, seed=s.seed, aug=tc.augment)
    if s.prior_steps and model.prior is not None:
        # a pretrained prior stays as it is: batches of 16 at the network's learning rate only
        # shook it (its L1 rose from 0.07 to 0.2 over 300 steps while the refinement trained)
        model.prior.requires_grad_(False)
    part_l = torch.as_tensor(train_set.landmark_parts, device=device) if train_set.landmark_parts is not None else None
    doubled = _doubled_ids(train_set)
    log_path = out_dir / "log.jsonl"
    B = s.batch

    def batches(start: int):
        for st in range(start, s.steps):
            yield st, make_batch(train_set, train_set.batch_indices(s.seed, st, B), cfg, tc.augment, (s.seed, st))

    def run_eval(at: int) -> dict | None:
        if val_set is None:
            return None
        m = evaluate_crops(model, val_set, s.eval_samples, B, device)
        m["step"] = at
        state["evals"].append(m)
        log.info(f"eval @ {at}: visible error {m['error_pct_box_visible']:.2f} % box height "
                 f"({m['error_px_visible']:.2f} crop px), visibility acc {m['visibility_accuracy']:.3f}, "
                 f"contact AUC {m.get('contact_auc')}, floor AUC {m.get('floor_contact_auc')}")
        model.train()
        return m

    model.train()
    t_run = time.perf_counter()
    t_start, step0 = time.perf_counter(), step
    t_log, seen_log = time.perf_counter(), 0
    running: dict[str, float] = {}
    amp = device.startswith("cuda")
    try:
        for st, b in threaded(lambda: batches(step), maxsize=2):
            for g in opt.param_groups:
                g["lr"] = lr_at(st, s)
            t = batch_to_torch(b, device)
            with torch.autocast("cuda", dtype=torch.bfloat16, enabled=amp):
                out_ = run_model(model, t)
            out_f = {k: v.float() for k, v in out_.items()}
            loss, terms = mammanet_loss(out_f, t, tc.loss, part_l, doubled)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if s.grad_clip:
                torch.nn.utils.clip_grad_norm_(model.parameters(), s.grad_clip)
            opt.step()
            step = st + 1
            seen_log += B
            for k, v in terms.items():
                running[k] = running.get(k, 0.0) + v
            if step % s.log_every == 0 or step == s.steps:
                n = (step - 1) % s.log_every + 1
                avg = {k: v / n for k, v in running.items()}
                dt = time.perf_counter() - t_log
                rate = seen_log / dt if dt > 0 else 0.0
                eta = (s.steps - step) * B / rate if rate > 0 else float("nan")
                rec = {"step": step, "lr": lr_at(st, s), **{k: round(v, 5) for k, v in avg.items()},
                       "samples_per_s": round(rate, 2)}
                state["history"].append(rec)
                with open(log_path, "a") as f:
                    f.write(json.dumps(rec) + "\n")
                log.info(f"step {step}/{s.steps} loss {avg['loss']:.4f} (nll {avg['nll']:.4f} vis {avg['vis']:.4f} "
                         f"contact {avg['contact']:.4f} floor {avg['floor']:.4f}"
                         + (f" dense {avg['dense']:.4f}" if "dense" in avg else "")
                         + (f" prior {avg['prior']:.4f}" if "prior" in avg else "")
                         + f") {rate:.1f} samples/s, eta {eta / 60:.1f} min")
                running, t_log, seen_log = {}, time.perf_counter(), 0
            if s.eval_every and step % s.eval_every == 0 and step < s.steps:
                run_eval(step)
            pause = (for_steps is not None and step - step0 >= for_steps) or \
                (for_minutes is not None and time.perf_counter() - t_start >= 60 * for_minutes)
            if step % s.ckpt_every == 0 or step == s.steps or pause:
                state["seconds"] += time.perf_counter() - t_run
                t_run = time.perf_counter()
                _save_checkpoint(ckpt_path, model, opt, step, tc, state)
            if pause and step < s.steps:
                log.info(f"paused at step {step}/{s.steps}: checkpoint {ckpt_path}; continue with --resume")
                return {"paused": True, "steps": step, "of": s.steps, "checkpoint": str(ckpt_path), "out": str(out_dir)}
    except KeyboardInterrupt:
        state["seconds"] += time.perf_counter() - t_run
        _save_checkpoint(ckpt_path, model, opt, step, tc, state)
        log.info(f"interrupted: checkpoint at step {step} saved to {ckpt_path}; continue with --resume")
        raise
    final = run_eval(step)
    if final is not None:
        _save_checkpoint(ckpt_path, model, opt, step, tc, state)
    return _finish(model, tc, train_set, val_set, step, state, final, out_dir, device)


def export(config_path: str | Path, out: str | None = None, device: str = "cpu",
           layout_visibility: bool = False) -> dict:
    """Weights + model card from a run's checkpoint as it stands (a run still in progress, or
    one stopped early): evaluated on the held-out shards, marked as step N of M in the card
    when the schedule is not done. ``layout_visibility``: fit the layout visibility head
    (landmarks/layout_vis.py) on the training crops and ship it in place of the decoder's."""
    tc = load_train_config(config_path, out)
    s = tc.settings
    ckpt_path = Path(s.out) / "checkpoint.pt"
    if not ckpt_path.is_file():
        raise UserError(f"no training checkpoint in {s.out}", "train first: `mamma-kit train CONFIG`")
    if s.threads:
        torch.set_num_threads(s.threads)
    ck = torch.load(ckpt_path, map_location="cpu", weights_only=True)
    if ck.get("format") != CHECKPOINT_FORMAT:
        raise UserError(f"{ckpt_path} is not a mamma-kit training checkpoint", "choose another output folder")
    cfg = MammaNetConfig.from_dict(ck["model_config"])
    tc.model = cfg
    model = MammaNet(cfg).to(device)
    model.load_state_dict(ck["model"])
    step, state = int(ck["step"]), json.loads(ck["state"])
    train_set = CropShards(tc.train_dirs)
    val_set = CropShards(tc.val_dirs) if tc.val_dirs else None
    if layout_visibility:
        from dataclasses import replace

        from mamma_kit.landmarks.layout_vis import fit_layout_visibility

        before = evaluate_crops(model, val_set, s.eval_samples, s.batch, device) if val_set is not None else {}
        head, info = fit_layout_visibility(model, tc.train_dirs)
        info["held_out_accuracy_of_the_decoder_visibility"] = before.get("visibility_accuracy")
        cfg = replace(cfg, layout_visibility=True)
        tc.model = cfg
        sd = model.state_dict()
        model = MammaNet(cfg).to(device)
        model.load_state_dict({**sd, **{f"layout_vis.{k}": v for k, v in head.state_dict().items()}})
        state = {**state, "layout_visibility": info}
    final = evaluate_crops(model, val_set, s.eval_samples, s.batch, device) if val_set is not None else None
    if final is not None:
        final["step"] = step
    if step < s.steps:
        state = {**state, "intermediate": {"step": step, "of": s.steps}}
    return _finish(model, tc, train_set, val_set, step, state, final, Path(s.out), device)


def _finish(model, tc: TrainConfig, train_set, val_set, step, state, final, out_dir: Path, device) -> dict:
    cfg = model.cfg
    card = {
        "model": {"arch": cfg.name, "config": cfg.to_dict(), "parameters": count_parameters(model),
                  "landmark_set": train_set.landmark_set},
        "data": {"train": train_set.describe(), "val": val_set.describe() if val_set else None,
                 "note": "synthetic renders (mamma-kit synth); no real images"},
        "training": {"steps": step, "batch": tc.settings.batch, "samples_seen": step * tc.settings.batch,
                     "seconds": round(state["seconds"], 1), "device": device, "torch": str(torch.__version__),
                     "mamma_kit": __version__, "machine": platform.machine(), "threads": torch.get_num_threads(),
                     "config_file": str(tc.path), "config_sha256": sha256_file(tc.path), "settings": tc.describe()},
        "metrics": final, "evals": state["evals"],
    }
    if state.get("intermediate"):
        card["training"]["intermediate"] = state["intermediate"]
    if state.get("layout_visibility"):
        card["training"]["layout_visibility"] = state["layout_visibility"]
    weights = save_weights(out_dir / f"{cfg.name}.pt", model.cpu(), train_set.landmark_set, card,
                           half=tc.settings.half_weights)
    write_json(out_dir / "model_card.json", card)
    atomic_write_text(out_dir / "model_card.md", model_card_markdown(card))
    summary = {"weights": str(weights), "size_mb": round(weights.stat().st_size / 1e6, 2), "steps": step,
               "metrics": final, "out": str(out_dir)}
    log.info(f"weights written to {weights} ({summary['size_mb']} MB) with model_card.md")
    return summary


def model_card_markdown(card: dict) -> str:
    m, d, t, met = card["model"], card["data"], card["training"], card.get("metrics") or {}

    def f(v, nd=2):
        return "n/a" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))

    lines = [
        f"# MammaNet `{m['arch']}`", "",
        f"- parameters: {m['parameters']:,}; input {m['config']['input_hw'][0]} x {m['config']['input_hw'][1]} (H x W); "
        f"{m['config']['n_landmarks']} landmarks ({m['landmark_set'] or 'unnamed set'}); "
        f"queries: {m['config']['queries']}; mask input: {m['config']['use_mask']}",
        f"- trained by `mamma-kit train {t['config_file']}` (sha256 {t['config_sha256'][:12]}), mamma-kit {t['mamma_kit']}, "
        f"torch {t['torch']} on {t['device']} ({t['threads']} threads)",
        f"- {t['steps']} steps x batch {t['batch']} = {t['samples_seen']} samples in {t['seconds'] / 3600:.2f} h"
        + (f" (an intermediate checkpoint: step {t['intermediate']['step']} of a {t['intermediate']['of']}-step "
           "schedule)" if t.get("intermediate") else ""),
    ]
    lv = t.get("layout_visibility")
    if lv:
        lines.append(f"- visibility: the layout head (landmarks/layout_vis.py) fitted after training on the network's "
                     f"predictions for {lv['predicted_crops']} training crops and {lv['train_crops']} noisy true layouts "
                     f"in {lv['seconds']:.0f} s; the decoder's own visibility scored "
                     f"{f(lv.get('held_out_accuracy_of_the_decoder_visibility'), 3)} on the held-out crops")
    lines += [
        "",
        "## Data", "",
        f"- train: {d['train']['samples']} crops from {', '.join(d['train']['dirs'])}; recipes {d['train']['recipes']}, "
        f"seeds {d['train']['seeds']}",
        f"- held out: " + (f"{d['val']['samples']} crops from {', '.join(d['val']['dirs'])}; recipes {d['val']['recipes']}, "
                           f"seeds {d['val']['seeds']}" if d.get("val") else "none"),
        f"- {d['note']}", "",
        "## Held-out metrics (network input crops, no augmentation, exact masks)", "",
        "| metric | value |", "|---|---|",
        f"| error, visible landmarks (% of box height) | {f(met.get('error_pct_box_visible'))} |",
        f"| error, all landmarks (% of box height) | {f(met.get('error_pct_box_all'))} |",
        f"| error, visible (crop px) | {f(met.get('error_px_visible'))} |",
        f"| visibility accuracy | {f(met.get('visibility_accuracy'), 3)} |",
        f"| person contact ROC AUC | {f(met.get('contact_auc'), 3)} |",
        f"| floor contact ROC AUC | {f(met.get('floor_contact_auc'), 3)} |",
        "", "Limitations: trained on synthetic renders only; expect a domain gap on real footage.", "",
    ]
    return "\n".join(lines)


__all__ = ["TrainConfig", "TrainSettings", "load_train_config", "train", "export", "evaluate_crops", "lr_at", "make_batch",
           "batch_to_torch", "run_model",
           "model_card_markdown"]
