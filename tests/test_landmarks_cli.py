"""`mamma-kit landmarks` on a small workspace: streaming network inference, --source gt, evaluation, doctor."""

import json

import numpy as np
import pytest
import torch

from mamma_kit.core.io import write_toml
from mamma_kit.core.tracks import LandmarkTracks, MaskTracks
from mamma_kit.landmarks.metrics import roc_auc

W, H, T = 160, 120, 5
# person rectangles per gt id (x1, y1, x2, y2), moving 3 px per frame
RECTS = {0: (20, 20, 60, 110), 1: (90, 10, 130, 100)}
LG = 200  # ground-truth landmarks per person (statistics of the noise)


def person_rect(pid, t):
    x1, y1, x2, y2 = RECTS[pid]
    return x1 + 3 * t, y1, x2 + 3 * t, y2


def _mask(pid, t):
    m = np.zeros((H, W), bool)
    x1, y1, x2, y2 = person_rect(pid, t)
    m[y1:y2, x1:x2] = True
    return m


@pytest.fixture
def ws(tmp_path):
    from mamma_kit.video import VideoReader, VideoWriter

    root = tmp_path / "ws"
    (root / "videos").mkdir(parents=True)
    rng = np.random.default_rng(0)
    with VideoWriter(root / "videos" / "cam0.mp4", W, H, fps=30) as vw:
        for t in range(T):
            img = np.full((H, W, 3), 60, np.uint8)
            for pid, col in ((0, (220, 80, 40)), (1, (40, 200, 90))):
                x1, y1, x2, y2 = person_rect(pid, t)
                img[y1:y2, x1:x2] = col
            img = np.clip(img + rng.normal(0, 5, img.shape), 0, 255).astype(np.uint8)
            vw.write_frame(img, t=t / 30 + (0.004 if t == 3 else 0.0))  # a little VFR
    times = VideoReader(root / "videos" / "cam0.mp4").timestamps
    write_toml(root / "capture.toml", {"capture": {"name": "t"}, "cameras": {"cam0": {"video": "videos/cam0.mp4"}}})
    # tracker output: track 7 shows person 1, track 3 person 0 (absent in frame 2)
    masks = {(t, 0): _mask(1, t) for t in range(T)}
    masks.update({(t, 1): _mask(0, t) for t in range(T) if t != 2})
    MaskTracks.from_masks("cam0", (W, H), times, np.array([7, 3]), masks).save(root / "masks" / "cam0.npz")
    # ground truth
    MaskTracks.from_masks("cam0", (W, H), times, np.array([0, 1]),
                          {(t, p): _mask(p, t) for t in range(T) for p in (0, 1)}).save(root / "gt" / "masks" / "cam0.npz")
    gt = LandmarkTracks.empty("cam0", (W, H), times, np.array([0, 1]), LG, "toy", "gt")
    for p in (0, 1):
        for t in range(T):
            x1, y1, x2, y2 = person_rect(p, t)
            gt.xy[t, p] = np.stack([rng.uniform(x1, x2, LG), rng.uniform(y1, y2, LG)], 1)
    gt.valid[:] = True
    gt.visibility[:] = rng.random((T, 2, LG)) > 0.3
    gt.contact[:] = rng.random((T, 2, LG)) > 0.9
    gt.floor_contact[:] = gt.xy[..., 1] > 95
    gt.save(root / "gt" / "landmarks" / "cam0.npz")
    return root


def test_network_inference_streams_the_video(ws, cli):
    from mamma_kit.landmarks.inference import Predictor
    from mamma_kit.landmarks.model import build_model
    from mamma_kit.landmarks.weights import load_model, save_weights
    from mamma_kit.video import VideoReader

    torch.manual_seed(0)
    model = build_model("tiny")
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    save_weights(ws / "tiny.pt", model, "toy-16")
    raw = ("--smooth-s", "0")  # the network's own numbers (no smoothing of contact and visibility)
    res = cli("landmarks", ws, "--weights", ws / "tiny.pt", "--batch", "3", *raw, "--json", "--quiet")
    assert res.code == 0, res
    summary = json.loads(res.out)
    assert summary["arch"] == "tiny" and summary["cameras"][0]["crops"] == 9
    lt = LandmarkTracks.load(ws / "landmarks" / "cam0.npz")
    masks = MaskTracks.load(ws / "masks" / "cam0.npz")
    assert np.array_equal(lt.valid, masks.present) and lt.landmark_set == "toy-16" and lt.source == "mammanet:tiny"
    assert np.array_equal(lt.track_ids, [7, 3]) and np.allclose(lt.frame_times, masks.frame_times)
    # the same numbers as running the predictor on each decoded frame (batching and streaming change nothing)
    pred = Predictor(load_model(ws / "tiny.pt"))
    for t, (_, img) in enumerate(VideoReader(ws / "videos" / "cam0.mp4").frames()):
        ks = np.flatnonzero(masks.present[t])
        ref = pred.predict_image(img, [masks.mask(t, k) for k in ks])
        assert np.allclose(lt.xy[t, ks], ref["xy"], atol=1e-3)
        assert np.allclose(lt.sigma[t, ks], ref["sigma"], rtol=1e-4)
        assert np.allclose(lt.visibility[t, ks], ref["visibility"], atol=1e-5)
    assert np.isnan(lt.xy[2, 1]).all() and not lt.valid[2, 1]
    assert "landmarks" in lt.producer["command"]
    again = cli("landmarks", ws, "--weights", ws / "tiny.pt", *raw, "--json", "--quiet")
    assert json.loads(again.out)["skipped"] is True
    # by default the contact and visibility are smoothed over time (landmarks/smooth.py): a changed
    # setting, so it recomputes; positions and sigma stay the network's
    smoothed = cli("landmarks", ws, "--weights", ws / "tiny.pt", "--json", "--quiet")
    assert json.loads(smoothed.out)["skipped"] is False
    from mamma_kit.landmarks.smooth import SMOOTH_S, smooth_landmarks

    lt_s = LandmarkTracks.load(ws / "landmarks" / "cam0.npz")
    want = smooth_landmarks(lt, SMOOTH_S)
    assert np.allclose(lt_s.visibility, want.visibility, atol=1e-6) and np.allclose(lt_s.contact, want.contact, atol=1e-6)
    assert np.allclose(lt_s.xy, lt.xy, atol=1e-3, equal_nan=True) and not np.allclose(lt_s.visibility, lt.visibility)
    forced = cli("landmarks", ws, "--weights", ws / "tiny.pt", "--force", "--json", "--quiet")
    assert json.loads(forced.out)["skipped"] is False


def test_missing_masks_is_a_user_error(ws, cli):
    from mamma_kit.landmarks.model import build_model
    from mamma_kit.landmarks.weights import save_weights

    save_weights(ws / "tiny.pt", build_model("tiny"))
    (ws / "masks" / "cam0.npz").unlink()
    res = cli("landmarks", ws, "--weights", ws / "tiny.pt")
    assert res.code == 2 and "mamma-kit track" in res.err and len(res.err.strip().splitlines()) == 1


def test_noisy_ground_truth_follows_the_mask_tracks(ws, cli):
    res = cli("landmarks", ws, "--source", "gt", "--noise", "2", "--outliers", "0.1", "--seed", "1", "--json", "-q")
    assert res.code == 0, res
    lt = LandmarkTracks.load(ws / "landmarks" / "cam0.npz")
    gt = LandmarkTracks.load(ws / "gt" / "landmarks" / "cam0.npz")
    assert np.array_equal(lt.track_ids, [7, 3])
    assert lt.valid[:, 0].all() and lt.valid[:, 1].sum() == T - 1 and not lt.valid[2, 1]
    # track 7 is gt person 1, track 3 gt person 0
    r = np.concatenate([(lt.xy[:, 0] - gt.xy[:, 1]).reshape(-1, 2), (lt.xy[lt.valid[:, 1], 1] - gt.xy[lt.valid[:, 1], 0])
                        .reshape(-1, 2)])
    far = np.linalg.norm(r, axis=1) > 10
    assert 0.06 < far.mean() < 0.12  # 10 % outliers, some of which land near their true point
    assert np.std(r[~far], axis=0) == pytest.approx([2.0, 2.0], rel=0.08)
    assert np.allclose(lt.sigma[lt.valid], 2.0)  # outliers get no larger sigma
    assert np.array_equal(lt.visibility[:, 0], gt.visibility[:, 1]) and np.array_equal(lt.contact[:, 0], gt.contact[:, 1])

    # noise relative to the box height: 2 % of 90 px (the rectangles are 90 px tall)
    res = cli("landmarks", ws, "--source", "gt", "--noise", "2%", "--json", "-q")
    lt = LandmarkTracks.load(ws / "landmarks" / "cam0.npz")
    assert np.allclose(lt.sigma[lt.valid], 0.02 * 90)

    # without masks the gt person ids are the tracks
    (ws / "masks" / "cam0.npz").unlink()
    res = cli("landmarks", ws, "--source", "gt", "--noise", "0", "--json", "-q")
    lt = LandmarkTracks.load(ws / "landmarks" / "cam0.npz")
    assert np.array_equal(lt.track_ids, [0, 1]) and np.allclose(lt.xy, gt.xy) and np.allclose(lt.sigma, 0.5)


def test_evaluation_of_noisy_ground_truth(ws, cli):
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.evaluation.landmarks import evaluate

    cli("landmarks", ws, "--source", "gt", "--noise", "3", "--seed", "2", "-q")
    m = evaluate(Workspace(ws))
    assert m["cameras"]["cam0"]["matched_by"] == "mask overlap" and m["instances"] == 2 * T - 1
    assert m["error_px_all"] == pytest.approx(3 * np.sqrt(np.pi / 2), rel=0.05)  # Rayleigh mean
    assert m["error_pct_box_all"] == pytest.approx(100 * m["error_px_all"] / 90, rel=1e-6)
    assert m["visibility_accuracy"] == 1.0 and m["contact_auc"] == 1.0 and m["floor_contact_auc"] == 1.0
    assert m["coverage"] == pytest.approx((2 * T - 1) / (2 * T))
    res = cli("eval", ws, "--only", "landmarks", "--json", "-q")
    assert res.code == 0 and json.loads(res.out)["landmarks"]["error_px_all"] == pytest.approx(m["error_px_all"])


def test_roc_auc_against_a_direct_count():
    rng = np.random.default_rng(0)
    y = rng.random(300) > 0.7
    s = rng.normal(0, 1, 300) + y + np.round(rng.random(300), 1)  # ties too
    pos, neg = s[y], s[~y]
    direct = ((pos[:, None] > neg[None]).sum() + 0.5 * (pos[:, None] == neg[None]).sum()) / (len(pos) * len(neg))
    assert roc_auc(s, y) == pytest.approx(direct, abs=1e-12)
    assert roc_auc(s, np.zeros(300)) is None


def test_doctor_reports_landmark_files(tmp_path, monkeypatch, cli):
    from mamma_kit.landmarks.model import build_model

    ck = tmp_path / "not_official.ckpt"
    torch.save({"state_dict": build_model("tiny").state_dict()}, ck)
    torch.save(torch.rand(512, 300), tmp_path / "verts_512.pkl")
    idx = np.random.default_rng(0).permutation(512)
    np.savez(tmp_path / "parts.npz", body=idx[:300], left_hand=idx[300:])
    monkeypatch.setenv("MAMMA_KIT_MAMMANET_CKPT", str(ck))
    monkeypatch.setenv("MAMMA_KIT_LANDMARK_VERTS", str(tmp_path / "verts_512.pkl"))
    monkeypatch.setenv("MAMMA_KIT_LANDMARK_PARTS", str(tmp_path / "parts.npz"))
    res = cli("doctor", "--json")
    checks = {c["name"]: c for c in json.loads(res.out)["checks"]}
    assert "MammaNet embedded weights" in checks
    assert checks["official MammaNet checkpoint"]["ok"] is False and "differs" in checks["official MammaNet checkpoint"]["detail"]
    assert checks["official landmark definition"]["ok"] is True and "300 vertices" in checks["official landmark definition"]["detail"]
    assert checks["official landmark body parts"]["ok"] is True
    monkeypatch.setenv("MAMMA_KIT_MAMMANET_CKPT", str(tmp_path / "nope.ckpt"))
    checks = {c["name"]: c for c in json.loads(cli("doctor", "--json").out)["checks"]}
    assert checks["official MammaNet checkpoint"]["ok"] is False and "not found" in checks["official MammaNet checkpoint"]["detail"]


def test_mask_areas_from_runs(ws):
    from mamma_kit.landmarks.inference import mask_areas

    masks = MaskTracks.load(ws / "masks" / "cam0.npz")
    rng = np.random.default_rng(5)
    blobs = {(t, k): rng.random((H, W)) > 0.6 + 0.1 * k for t in range(3) for k in range(2) if (t, k) != (1, 1)}
    blobs[(2, 0)] = np.ones((H, W), bool)  # a mask starting with foreground (a 0-length first run)
    mt = MaskTracks.from_masks("c", (W, H), np.arange(3) / 30, np.array([1, 2]), blobs)
    areas = mask_areas(mt)
    assert areas.tolist() == [[mt.area(t, k) for k in range(2)] for t in range(3)]
    assert mask_areas(masks)[0].tolist() == [40 * 90, 40 * 90]


def test_the_contact_head_comes_from_the_single_query_network_under_a_keypoint_guided_one():
    """"auto": the shipped single-query network's contact head under the keypoint-guided model (it
    reads contact better), none under an image-only model; "off" none; a keypoint-guided network
    offered as the contact network is a user error."""
    from mamma_kit.core.errors import UserError
    from mamma_kit.landmarks.stage import EMBEDDED_CONTACT, contact_network
    from mamma_kit.landmarks.weights import EMBEDDED_DIR, load_model

    kp = load_model(EMBEDDED_DIR / "embedded-kp.pt")
    chosen = contact_network(kp, "auto")
    assert chosen is not None and chosen.source.endswith(EMBEDDED_CONTACT) and chosen.config.keypoints_in == 0
    assert contact_network(kp, "off") is None
    assert contact_network(load_model(EMBEDDED_DIR / "embedded.pt"), "auto") is None
    with pytest.raises(UserError, match="image-only"):
        contact_network(kp, EMBEDDED_DIR / "embedded-kp.pt")


def test_the_contact_network_reads_only_people_near_another():
    """Person contact needs another person near in the image (touching people's boxes meet in
    every view that sees both): a person whose box, grown by a tenth of its height, meets no other
    tracked person's box is not given to the contact network (its contact is 0)."""
    from mamma_kit.landmarks.inference import alone_in_frame

    nan = np.nan
    boxes = np.array([[0, 0, 10, 20], [12, 0, 22, 20], [100, 100, 110, 120], [nan, nan, nan, nan],
                      [0, 50, 10, 70]], float)
    assert not alone_in_frame(boxes, 0) and not alone_in_frame(boxes, 1)  # 2 px apart: within 2 px
    assert alone_in_frame(boxes, 2)  # far from everyone
    assert alone_in_frame(boxes, 4)  # 30 px below the first: beyond its grown box (2 px)
    assert alone_in_frame(boxes[[2, 3]], 0)  # an absent track (NaN) is nobody
