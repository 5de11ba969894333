"""MammaNet configs, forward contract, weight files and losses."""

import math

import numpy as np
import pytest
import torch

from mamma_kit.core.errors import UserError
from mamma_kit.landmarks.config import CONFIGS, MammaNetConfig, get_config
from mamma_kit.landmarks.losses import gaussian_nll, landmark_weights, mammanet_loss, sigmoid_focal
from mamma_kit.landmarks.model import build_model, count_parameters, state_dict_shapes
from mamma_kit.landmarks.weights import load_model, save_weights


@pytest.mark.parametrize("name", ["tiny", "tiny-single"])
@pytest.mark.parametrize("use_mask", [True, False])
def test_forward_shapes_and_mask_input(name, use_mask):
    torch.manual_seed(0)
    cfg = get_config(name, use_mask=use_mask)
    model = build_model(cfg).eval()
    with torch.no_grad():  # break the zero-initialised head so outputs depend on the input
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    H, W = cfg.input_hw
    x = torch.randn(3, 3, H, W)
    m = (torch.rand(3, 1, H, W) > 0.5).float()
    with torch.no_grad():
        out = model(x, m)
        other = model(x, 1 - m)
    L = cfg.n_landmarks
    assert out["xy"].shape == (3, L, 2) and out["log_sigma"].shape == (3, L)
    for k in ("vis_logit", "contact_logit", "floor_logit"):
        assert out[k].shape == (3, L)
    assert torch.allclose(out["xy"], other["xy"]) != use_mask  # the mask enters only when configured
    assert (model.mask_downscaling is not None) == use_mask


def test_single_query_baseline_has_one_query():
    single = dict(state_dict_shapes("embedded-single"))
    per = dict(state_dict_shapes("embedded"))
    assert single["decoder.query_embed.weight"] == (1, 128) and per["decoder.query_embed.weight"] == (512, 128)
    assert single["decoder.landmarks.layers.2.weight"] == (3 * 512, 128) and single["decoder.vis_prob.weight"] == (512, 128)
    # same stem, backbone and mask embedding: the ablation changes the decoder only
    assert {k: v for k, v in single.items() if not k.startswith("decoder.")} == \
        {k: v for k, v in per.items() if not k.startswith("decoder.")}


def test_embedded_configs_fit_the_package_budget():
    for name in ("embedded", "embedded-256", "embedded-single"):
        with torch.device("meta"):
            n = count_parameters(build_model(name, device="meta"))
        assert n * 2 < 25e6, name  # float16 weights stay under 25 MB
    assert CONFIGS["embedded"].grid_hw == (24, 18) and CONFIGS["official"].grid_hw == (32, 24)


def test_config_validation_and_roundtrip():
    cfg = get_config("embedded-256")
    assert MammaNetConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(UserError, match="3:4"):
        get_config("tiny", input_hw=(64, 64))
    with pytest.raises(UserError, match="mask embedding grid"):
        get_config("tiny", mask_strides=(4, 4))
    with pytest.raises(UserError, match="unknown MammaNet architecture"):
        get_config("vit-huge")


def test_weight_file_roundtrip(tmp_path):
    torch.manual_seed(0)
    model = build_model("tiny").eval()
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    x = torch.randn(2, 3, 64, 48)
    m = torch.ones(2, 1, 64, 48)
    save_weights(tmp_path / "t.pt", model, "toy-16", {"steps": 7})
    save_weights(tmp_path / "t16.pt", model, "toy-16", half=True)
    loaded = load_model(tmp_path / "t.pt")
    assert loaded.config == model.cfg and loaded.landmark_set == "toy-16" and loaded.card["steps"] == 7
    with torch.no_grad():
        a, b = model(x, m), loaded.model(x, m)
        c = load_model(tmp_path / "t16.pt").model(x, m)
    assert torch.equal(a["xy"], b["xy"])
    assert torch.allclose(a["xy"], c["xy"], atol=5e-3)  # float16 storage
    with pytest.raises(UserError, match="holds a 'tiny' MammaNet, not 'embedded'"):
        load_model(tmp_path / "t.pt", arch="embedded")


@pytest.mark.parametrize("over", [{"dense_head": True, "stem": "conv"}, {"layout_visibility": True}])
def test_weight_file_roundtrip_with_derived_buffers_and_heads(tmp_path, over):
    """The dense head's cell centres are a derived buffer (not in the file) and the layout head is
    an extra module: both must load, and give the saved model's outputs."""
    torch.manual_seed(0)
    model = build_model(get_config("tiny", **over)).eval()
    save_weights(tmp_path / "d.pt", model)
    loaded = load_model(tmp_path / "d.pt").model
    x, m = torch.randn(2, 3, 64, 48), torch.ones(2, 1, 64, 48)
    with torch.no_grad():
        a, b = model(x, m), loaded(x, m)
    assert torch.equal(a["xy"], b["xy"]) and torch.equal(a["vis_logit"], b["vis_logit"])


def test_missing_embedded_weights_is_a_user_error(monkeypatch, tmp_path, cli):
    import mamma_kit.landmarks.weights as W

    monkeypatch.setattr(W, "EMBEDDED_DIR", tmp_path)
    with pytest.raises(UserError, match="embedded MammaNet weights"):
        load_model()
    res = cli("landmarks", str(tmp_path))
    assert res.code == 2 and "mamma-kit train" in res.err and len(res.err.strip().splitlines()) == 1


# ---- losses -----------------------------------------------------------------------------------
def test_gaussian_nll_minimum_and_clip():
    d = torch.tensor([[0.3]])
    xy_gt = torch.zeros(1, 1, 2)
    xy = torch.tensor([[[0.3, 0.0]]])
    ls = torch.linspace(-5, 1, 2001)
    vals = torch.stack([gaussian_nll(xy, s.view(1, 1), xy_gt)[0, 0] for s in ls])
    best = float(torch.exp(ls[vals.argmin()]))
    assert best == pytest.approx(float(d) / math.sqrt(2), rel=1e-2)  # sigma^2 = d^2 / 2 for 2-D isotropic
    far = gaussian_nll(torch.tensor([[[50.0, 0.0]]]), torch.tensor([[0.0]]), xy_gt)
    assert float(far) == pytest.approx(25.0)  # clipped at 25 (+ 2 log 1)


def test_focal_loss_values():
    logits = torch.tensor([[2.0, -2.0, 0.0]])
    t = torch.tensor([[1.0, 1.0, 0.0]])
    fl = sigmoid_focal(logits, t, 0.9, 2.0)
    p = torch.sigmoid(logits)
    expected = torch.stack([0.9 * (1 - p[0, 0]) ** 2 * -torch.log(p[0, 0]),
                            0.9 * (1 - p[0, 1]) ** 2 * -torch.log(p[0, 1]),
                            0.1 * p[0, 2] ** 2 * -torch.log(1 - p[0, 2])])
    assert torch.allclose(fl[0], expected, atol=1e-6)


def test_landmark_weights_inside_outside_and_doubled_parts():
    # parts: 0 body, 1 left hand; landmarks 0,1 body; 2,3 hand
    part = torch.tensor([0, 0, 1, 1])
    xy = torch.tensor([[[0.0, 0.0], [1.5, 0.0], [0.9, 0.9], [1.2, -0.3]],     # hand partly inside
                       [[0.0, 0.0], [-0.2, 1.25], [1.5, 0.0], [2.0, 2.0]]])   # hand fully outside
    w = landmark_weights(xy, part, [1])
    e = math.exp
    assert torch.allclose(w[0], torch.tensor([1.0, e(-1.0), 2.0, 2 * e(-0.4)]), atol=1e-6)
    assert torch.allclose(w[1], torch.tensor([1.0, e(-0.5), e(-1.0), e(-2.0)]), atol=1e-6)


def test_total_loss_weights_and_gradients():
    B, L = 2, 4
    out = {"xy": torch.zeros(B, L, 2, requires_grad=True), "log_sigma": torch.zeros(B, L, requires_grad=True),
           "vis_logit": torch.zeros(B, L), "contact_logit": torch.zeros(B, L), "floor_logit": torch.zeros(B, L)}
    batch = {"xy_n": torch.full((B, L, 2), 0.1), "visibility": torch.ones(B, L), "contact": torch.zeros(B, L),
             "floor_contact": torch.zeros(B, L)}
    total, terms = mammanet_loss(out, batch)
    nll = 0.02 / 2  # d^2 = 0.02, sigma = 1
    bce = math.log(2)
    focal_neg = 0.1 * 0.25 * math.log(2)
    assert terms["nll"] == pytest.approx(nll, rel=1e-5) and terms["vis"] == pytest.approx(bce, rel=1e-5)
    assert terms["contact"] == pytest.approx(focal_neg, rel=1e-5)
    assert float(total.detach()) == pytest.approx(100 * nll + bce + 2 * focal_neg, rel=1e-5)
    total.backward()
    assert (out["xy"].grad < 0).all()  # pulls predictions towards the targets
    assert np.isfinite(out["log_sigma"].grad.numpy()).all()


def test_dense_head_centres_and_conv_stem_shapes():
    """The conv stem gives the token grid of its patch size; the dense head's cells sit at the
    centres of the input pixels they cover (normalised units), and its soft-argmax of a
    one-hot logit map is that cell's centre."""
    from mamma_kit.landmarks.model import MammaNet

    cfg = get_config("embedded")
    m = MammaNet(cfg).eval()
    with torch.no_grad():
        f, fine = m.features(torch.zeros(1, 3, *cfg.input_hw), torch.ones(1, 1, *cfg.input_hw))
    assert tuple(f.shape[-2:]) == cfg.grid_hw and tuple(fine.shape[-2:]) == (2 * cfg.grid_hw[0], 2 * cfg.grid_hw[1])
    c = m.dense.centres_n2
    gh, gw = 2 * cfg.grid_hw[0], 2 * cfg.grid_hw[1]
    assert c.shape == (gh * gw, 2)
    step = cfg.patch / 2  # the fine map: twice the token resolution
    assert torch.allclose(c[0], torch.tensor([step / cfg.input_hw[1] - 1, step / cfg.input_hw[0] - 1]))
    from mamma_kit.landmarks.losses import dense_cross_entropy

    xy = c[None, [7, 300]]  # two landmarks exactly at cell centres
    logits = torch.full((1, len(c), 2), -30.0)
    logits[0, 7, 0] = logits[0, 300, 1] = 30.0
    prob = torch.softmax(logits, 1)
    assert torch.allclose(torch.einsum("bnl,nc->blc", prob, c), xy, atol=1e-6)
    # a prediction shaped like the target (a Gaussian around the truth) beats a flat one
    d = torch.stack([c[1, 0] - c[0, 0], c[gw, 1] - c[0, 1]])
    z = (c[None, :, None] - xy[:, None]) / (0.6 * d)
    good = -0.5 * (z * z).sum(-1)
    assert (dense_cross_entropy(good, c, xy) < dense_cross_entropy(torch.zeros_like(good), c, xy) - 2).all()


def test_mask_in_stem_and_detached_decoder_memory():
    """mask_in_stem: the stem's first convolution reads the mask as a 4th channel (the tokens
    change with the mask even without the late mask embedding's help); detach_decoder_memory:
    the decoder's losses leave the backbone's gradient untouched, the dense head's reach it."""
    from mamma_kit.landmarks.model import MammaNet

    torch.manual_seed(0)
    cfg = get_config("tiny", stem="conv", dense_head=True, mask_in_stem=True, detach_decoder_memory=True)
    m = MammaNet(cfg)
    assert m.backbone.patch_embed.down[0][0].in_channels == 4
    img = torch.randn(2, 3, *cfg.input_hw)
    mask = torch.zeros(2, 1, *cfg.input_hw)
    mask[:, :, 8:40, 10:30] = 1
    tok_a, _ = m.backbone(torch.cat([img, mask], 1))
    tok_b, _ = m.backbone(torch.cat([img, 1 - mask], 1))
    assert not torch.allclose(tok_a, tok_b)
    qkv = m.backbone.blocks[0].attn.qkv.weight
    out = m(img, mask)
    out["vis_logit"].sum().backward()  # decoder only
    assert qkv.grad is None or float(qkv.grad.abs().max()) == 0.0
    m.zero_grad()
    out = m(img, mask)
    out["xy_dense"].sum().backward()
    assert float(qkv.grad.abs().max()) > 0.0
    with pytest.raises(UserError):
        get_config("tiny", mask_in_stem=True)  # needs the conv stem
