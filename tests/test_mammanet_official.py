"""Issue 11: the official MammaNet architecture, checkpoint loading and its documented quirks."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from mamma_kit.core.errors import UserError
from mamma_kit.landmarks.config import get_config
from mamma_kit.landmarks.model import MammaNet, build_model, state_dict_shapes
from mamma_kit.landmarks.weights import load_model

REPO = Path(__file__).resolve().parents[1]
KEYS = REPO.parent / "shared" / "official-mammanet-keys.txt"


def _fmt(name, shape):
    return f"{name} ({', '.join(map(str, shape))}{',' if len(shape) == 1 else ''})"


@pytest.fixture(scope="module")
def official_keys():
    if not KEYS.is_file():
        pytest.skip(f"{KEYS} not present (CI has shared/ beside the repo)")
    return [line.strip() for line in KEYS.read_text().splitlines() if line.strip()]


def test_official_state_dict_matches_the_checkpoint_exactly(official_keys):
    shapes = state_dict_shapes("official")
    assert [_fmt(k, s) for k, s in shapes] == official_keys  # names, shapes and order
    assert len(shapes) == 282
    assert sum(math.prod(s) for _, s in shapes) == 135_099_266


def test_describe_prints_the_official_names(cli, official_keys):
    res = cli("landmarks", "--arch", "official", "--describe")
    assert res.code == 0, res
    assert res.out.strip().splitlines() == official_keys


def test_lightning_checkpoint_loads_strictly_and_runs_on_a_crop(tmp_path):
    g = torch.Generator().manual_seed(0)
    sd = {}
    for k, s in state_dict_shapes("official"):
        noise = (torch.rand(s, generator=g) - 0.5) * 0.04
        sd[k] = noise + 1.0 if "norm" in k and k.endswith(".weight") else noise
    ckpt = tmp_path / "mamma_mask_full_cvpr.ckpt"
    torch.save({"epoch": 41, "global_step": 123456, "pytorch-lightning_version": "2.2.0", "state_dict": sd,
                "hyper_parameters": {"lr": 1e-4, "batch_size": 24}}, ckpt)
    loaded = load_model(ckpt, arch="official")
    msd = loaded.model.state_dict()
    assert list(msd) == list(sd) and all(torch.equal(msd[k], sd[k]) for k in sd)
    assert loaded.landmark_set == "official-smplx-512"
    assert load_model(ckpt).config.name == "official"  # recognised from its shapes without --arch
    del sd, msd

    from mamma_kit.landmarks.inference import Predictor

    torch.set_num_threads(min(2, torch.get_num_threads()))
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 255, (720, 1280, 3), dtype=np.uint8)
    mask = np.zeros((720, 1280), bool)
    mask[100:700, 500:760] = True
    pred = Predictor(loaded)
    img, m, box = pred.crop(frame, mask)
    assert img.shape == (512, 384, 3) and m.shape == (512, 384)
    out = pred.predict_image(frame, [mask])
    assert out["xy"].shape == (1, 512, 2) and np.isfinite(out["xy"]).all()
    assert (out["sigma"] > 0).all() and ((out["visibility"] >= 0) & (out["visibility"] <= 1)).all()
    # outputs are mapped through the documented box: x = cx + n * bw / 2
    net = pred.predict_crops(img[None], m[None])
    assert np.allclose(out["xy"][0], box[:2] + net["xy_n"][0] * box[2:] / 2, atol=1e-3)


class _NotAWeight:
    def __init__(self):
        self.x = 1


def test_checkpoint_needing_unpickling_is_refused(tmp_path, cli):
    p = tmp_path / "pickled.ckpt"
    torch.save({"state_dict": {"a": torch.zeros(2)}, "hyper_parameters": _NotAWeight()}, p)
    with pytest.raises(UserError, match="unpickling"):
        load_model(p, arch="official")
    res = cli("landmarks", "--arch", "official", "--weights", p)
    assert res.code == 2 and len(res.err.strip().splitlines()) == 1 and "re-save" in res.err


def test_missing_checkpoint_one_clear_line(cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = cli("landmarks", "--arch", "official", "--weights", "missing.ckpt")
    assert res.code == 2
    lines = res.err.strip().splitlines()
    assert len(lines) == 1 and "missing.ckpt" in lines[0] and "not found" in lines[0] and "Traceback" not in res.err


def test_wrong_architecture_is_a_clear_error(tmp_path):
    cfg = get_config("tiny")
    p = tmp_path / "bare.ckpt"
    torch.save({"state_dict": build_model(cfg).state_dict()}, p)
    with pytest.raises(UserError, match="does not fit the 'official'.*missing"):
        load_model(p, arch="official")
    assert load_model(p).config.name == "tiny"  # recognised from its shapes


# ---- the documented quirks, checked against a functional re-statement of the contract -----------
def _mha(q, k, v, w, b, ow, ob, heads):
    D = q.shape[-1]
    wq, wk, wv = w.split(D)
    bq, bk, bv = b.split(D)
    Q, K, V = F.linear(q, wq, bq), F.linear(k, wk, bk), F.linear(v, wv, bv)
    B = q.shape[0]
    sh = lambda x: x.reshape(B, -1, heads, D // heads).transpose(1, 2)  # noqa: E731
    a = torch.softmax(sh(Q) @ sh(K).transpose(-1, -2) / math.sqrt(D // heads), -1) @ sh(V)
    return F.linear(a.transpose(1, 2).reshape(B, -1, D), ow, ob)


def _ln2d(x, w, b):
    u = x.mean(1, keepdim=True)
    s = ((x - u) ** 2).mean(1, keepdim=True)
    return w[:, None, None] * (x - u) / torch.sqrt(s + 1e-6) + b[:, None, None]


def _reference(sd, cfg, img, mask):
    D = cfg.dim
    x = F.conv2d(img, sd["backbone.patch_embed.proj.weight"], sd["backbone.patch_embed.proj.bias"],
                 stride=16, padding=2)  # quirk: padding 2
    B, _, gh, gw = x.shape
    pe = sd["backbone.pos_embed"]
    t = x.flatten(2).transpose(1, 2) + pe[:, 1:] + pe[:, :1]  # quirk: row 0 added to every token
    for i in range(cfg.depth):
        p = f"backbone.blocks.{i}."
        h = F.layer_norm(t, (D,), sd[p + "norm1.weight"], sd[p + "norm1.bias"], eps=1e-6)
        qkv = F.linear(h, sd[p + "attn.qkv.weight"], sd[p + "attn.qkv.bias"]).reshape(B, -1, 3, cfg.heads, D // cfg.heads)
        q, k, v = qkv.permute(2, 0, 3, 1, 4)
        a = torch.softmax(q @ k.transpose(-1, -2) * (D // cfg.heads) ** -0.5, -1) @ v
        t = t + F.linear(a.transpose(1, 2).reshape(B, -1, D), sd[p + "attn.proj.weight"], sd[p + "attn.proj.bias"])
        h = F.layer_norm(t, (D,), sd[p + "norm2.weight"], sd[p + "norm2.bias"], eps=1e-6)
        t = t + F.linear(F.gelu(F.linear(h, sd[p + "mlp.fc1.weight"], sd[p + "mlp.fc1.bias"])),
                         sd[p + "mlp.fc2.weight"], sd[p + "mlp.fc2.bias"])
    t = F.layer_norm(t, (D,), sd["backbone.last_norm.weight"], sd["backbone.last_norm.bias"], eps=1e-6)
    m = "mask_downscaling.mask_downscaling."
    e = F.gelu(_ln2d(F.conv2d(mask, sd[m + "0.weight"], sd[m + "0.bias"], stride=4), sd[m + "1.weight"], sd[m + "1.bias"]))
    e = F.gelu(_ln2d(F.conv2d(e, sd[m + "3.weight"], sd[m + "3.bias"], stride=4), sd[m + "4.weight"], sd[m + "4.bias"]))
    e = F.conv2d(e, sd[m + "6.weight"], sd[m + "6.bias"])
    memory = t + e.flatten(2).transpose(1, 2)  # quirk: mask added after last_norm
    pos = pe[:, 1:]  # memory positions without row 0
    qpos = sd["decoder.query_embed.weight"][None].expand(B, -1, -1)
    tgt = torch.zeros_like(qpos)
    for i in range(cfg.dec_layers):  # post-norm DETR layers
        p = f"decoder.decoder_detr.layers.{i}."
        ln = lambda x, n: F.layer_norm(x, (D,), sd[p + n + ".weight"], sd[p + n + ".bias"], eps=1e-5)  # noqa: E731
        sa = _mha(tgt + qpos, tgt + qpos, tgt, sd[p + "self_attn.in_proj_weight"], sd[p + "self_attn.in_proj_bias"],
                  sd[p + "self_attn.out_proj.weight"], sd[p + "self_attn.out_proj.bias"], cfg.dec_heads)
        tgt = ln(tgt + sa, "norm1")
        ca = _mha(tgt + qpos, memory + pos, memory, sd[p + "multihead_attn.in_proj_weight"],
                  sd[p + "multihead_attn.in_proj_bias"], sd[p + "multihead_attn.out_proj.weight"],
                  sd[p + "multihead_attn.out_proj.bias"], cfg.dec_heads)
        tgt = ln(tgt + ca, "norm2")
        ff = F.linear(F.gelu(F.linear(tgt, sd[p + "linear1.weight"], sd[p + "linear1.bias"])),
                      sd[p + "linear2.weight"], sd[p + "linear2.bias"])
        tgt = ln(tgt + ff, "norm3")
    hs = F.layer_norm(tgt, (D,), sd["decoder.decoder_detr.norm.weight"], sd["decoder.decoder_detr.norm.bias"], eps=1e-5)
    r = hs
    for i in range(3):
        r = F.linear(r, sd[f"decoder.landmarks.layers.{i}.weight"], sd[f"decoder.landmarks.layers.{i}.bias"])
        r = F.relu(r) if i < 2 else r
    logit = lambda n: F.linear(hs, sd[f"decoder.{n}.weight"], sd[f"decoder.{n}.bias"])[..., 0]  # noqa: E731
    return r, logit("vis_prob"), logit("contact_prob"), logit("floor_contact_prob")


def test_official_quirks_match_a_functional_reference():
    # the official layout at reduced depth / input so the check is fast; same code paths
    cfg = get_config("official", depth=2, dec_layers=2, input_hw=(128, 96), n_landmarks=8, dim=96, mlp_dim=192,
                     dec_ffn=128)
    torch.manual_seed(1)
    model = MammaNet(cfg).eval()
    with torch.no_grad():  # make every parameter matter (biases and norms are 0 / 1 at init)
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    sd = model.state_dict()
    img = torch.randn(2, 3, 128, 96)
    mask = (torch.rand(2, 1, 128, 96) > 0.5).float()
    with torch.no_grad():
        out = model(img, mask)
        r, vis, con, flo = _reference(sd, cfg, img, mask)
    assert torch.allclose(out["xy"], r[..., :2], atol=1e-4) and torch.allclose(out["log_sigma"], r[..., 2], atol=1e-4)
    for a, b in ((out["vis_logit"], vis), (out["contact_logit"], con), (out["floor_logit"], flo)):
        assert torch.allclose(a, b, atol=1e-4)
    # and the mask really enters: another mask changes the outputs
    with torch.no_grad():
        assert not torch.allclose(model(img, 1 - mask)["xy"], out["xy"], atol=1e-4)
