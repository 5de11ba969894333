"""The sam2 backend: chunked propagation with bounded memory, ids carried across chunks, prompts.

SAM 2 itself is not installed here (it needs torchvision) and its weights are the user's, so the
chunking is tested with a stand-in predictor that has SAM 2's video-predictor interface and
really segments the JPEG frames the backend writes (by colour, following the previous mask).
The real predictor runs in `test_real_sam2` when the package and a checkpoint are present
(MAMMA_SAM2_CHECKPOINT, MAMMA_SAM2_CONFIG).
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from mamma_kit.core.errors import UserError
from mamma_kit.core.io import write_toml
from mamma_kit.core.tracks import MaskTracks
from mamma_kit.video.writer import VideoWriter

W, H, T = 160, 96, 30
COLOURS = {5: (220, 40, 40), 9: (40, 200, 60), 3: (40, 60, 220)}


def _boxes(t: int) -> dict[int, tuple[int, int, int, int]]:
    out = {5: (10 + 2 * t, 20, 30 + 2 * t, 70), 9: (120 - t, 30, 140 - t, 80)}
    if t >= 17:  # a third person walks in at frame 17
        out[3] = (60 + (t - 17), 2, 90 + (t - 17), 17)  # above the others: no overlap
    return out


def _draw():
    frames = np.full((T, H, W, 3), 128, np.uint8)
    truth = {}
    for t in range(T):
        for k, (x1, y1, x2, y2) in _boxes(t).items():
            frames[t, y1:y2, x1:x2] = COLOURS[k]
            m = np.zeros((H, W), bool)
            m[y1:y2, x1:x2] = True
            truth[(t, k)] = m
    return frames, truth


class StandInPredictor:
    """SAM 2's video-predictor interface over a colour follower; records what it was given."""

    def __init__(self):
        self.states = []
        self.max_frames = 0

    def init_state(self, video_path, offload_video_to_cpu=False, offload_state_to_cpu=False, **_):
        files = sorted(Path(video_path).glob("*.jpg"))
        frames = [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in files]
        self.max_frames = max(self.max_frames, len(frames))
        st = {"frames": frames, "objs": {}, "offload": (offload_video_to_cpu, offload_state_to_cpu)}
        self.states.append(st)
        return st

    def _from_mask(self, st, obj, mask):
        img = st["frames"][0].astype(float)
        st["objs"][obj] = (np.median(img[mask], 0), mask)

    def add_new_points_or_box(self, inference_state, frame_idx, obj_id, points=None, labels=None, box=None, **_):
        assert frame_idx == 0
        img = inference_state["frames"][0].astype(float)
        m = np.zeros(img.shape[:2], bool)
        if box is not None:
            x1, y1, x2, y2 = np.round(box).astype(int)
            m[y1:y2, x1:x2] = True
            m &= np.abs(img - 128).sum(-1) > 60  # the box's non-background pixels
        else:
            for (x, y), lab in zip(points, labels):
                if lab == 1:
                    c = img[int(y), int(x)]
                    m |= np.abs(img - c).sum(-1) < 40
        self._from_mask(inference_state, obj_id, m)

    def add_new_mask(self, inference_state, frame_idx, obj_id, mask):
        assert frame_idx == 0
        self._from_mask(inference_state, obj_id, np.asarray(mask, bool))

    def propagate_in_video(self, inference_state):
        ids = sorted(inference_state["objs"])
        prev = {o: inference_state["objs"][o][1] for o in ids}
        for f, img in enumerate(inference_state["frames"]):
            img = img.astype(float)
            logits = []
            for o in ids:
                col = inference_state["objs"][o][0]
                near = cv2.dilate(prev[o].astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
                m = (np.abs(img - col).sum(-1) < 60) & near
                prev[o] = m
                logits.append(np.where(m, 5.0, -5.0)[None])
            yield f, ids, np.stack(logits)

    def reset_state(self, inference_state):
        inference_state["frames"] = None


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    root = tmp_path_factory.mktemp("sam2")
    frames, truth = _draw()
    (root / "videos").mkdir()
    with VideoWriter(root / "videos" / "cam0.mp4", W, H, fps=30, crf=12) as w:
        for t, f in enumerate(frames):
            w.write_frame(f, t / 30)
    write_toml(root / "capture.toml", {"cameras": {"cam0": {"video": "videos/cam0.mp4"}}})
    return root, truth


def _iou(a, b):
    return np.count_nonzero(a & b) / max(np.count_nonzero(a | b), 1)


def test_chunked_propagation_keeps_ids_and_bounds_memory(video, tmp_path):
    from mamma_kit.masks.base import CameraInput
    from mamma_kit.masks.sam2 import Sam2Backend

    root, truth = video
    prompts = tmp_path / "prompts.toml"
    write_toml(prompts, {"cam0": [{"track": 5, "frame": 0, "box": [8, 18, 32, 72]},
                                  {"track": 9, "frame": 0, "points": [[130, 50], [128, 70]]},
                                  {"track": 3, "time_s": 17 / 30, "box": [58, 0, 92, 19]}]})
    pred = StandInPredictor()
    chunk = 8
    bk = Sam2Backend(prompts=prompts, chunk=chunk, predictor=pred)
    mt, summary = bk.track_camera(CameraInput("cam0", root / "videos" / "cam0.mp4", root))
    assert sorted(mt.track_ids.tolist()) == [3, 5, 9]  # the prompts' ids, kept
    assert pred.max_frames <= chunk and summary["max_frames_in_state"] <= chunk
    assert all(s["offload"] == (True, True) for s in pred.states)
    assert len(pred.states) >= (T - 1) // (chunk - 1) + 1  # a chunk every chunk-1 frames (+ the prompt's)
    assert 17 in summary["chunk_starts"]  # a chunk starts on the late prompt's frame
    for (t, k), m in truth.items():
        col = mt.track_column(k)
        got = mt.mask(t, col)
        assert got is not None, (t, k)
        assert _iou(got, m) > 0.8, (t, k, _iou(got, m))  # the stand-in's colour follower blurs edges
    # person 3 does not exist before its prompt
    assert not mt.present[:17, mt.track_column(3)].any()


def test_prompt_file_errors(tmp_path):
    from mamma_kit.masks.sam2 import load_prompts

    p = tmp_path / "p.toml"
    write_toml(p, {"cam0": [{"frame": 0, "box": [0, 0, 5, 5]}]})
    with pytest.raises(UserError, match="no 'track'"):
        load_prompts(p)
    write_toml(p, {"cam0": [{"track": 1, "frame": 0, "box": [5, 0, 1, 5]}]})
    with pytest.raises(UserError, match="x2 > x1"):
        load_prompts(p)
    write_toml(p, {"cam0": [{"track": 1, "frame": 0}]})
    with pytest.raises(UserError, match="exactly one of 'box' or 'points'"):
        load_prompts(p)
    write_toml(p, {"cam0": [{"track": 1, "frame": 0, "points": [[1, 2]], "labels": [1, 0]}]})
    with pytest.raises(UserError, match="labels for 1 points"):
        load_prompts(p)


def test_cli_sam2_errors(video, cli, tmp_path):
    root, _ = video
    r = cli("track", root, "--backend", "sam2", "--sam2-checkpoint", tmp_path / "none.pt", "--sam2-config", "x.yaml")
    assert r.code == 2 and ("checkpoint not found" in r.err or "sam2' package" in r.err), r


def test_real_sam2(video, tmp_path):
    try:
        import sam2  # noqa: F401
    except ImportError:
        pytest.skip("the sam2 package is not installed (pip install sam2; it needs torchvision)")
    ckpt, cfg = os.environ.get("MAMMA_SAM2_CHECKPOINT"), os.environ.get("MAMMA_SAM2_CONFIG")
    if not ckpt or not Path(ckpt).is_file() or not cfg:
        pytest.skip("no SAM 2 checkpoint: set MAMMA_SAM2_CHECKPOINT and MAMMA_SAM2_CONFIG")
    from mamma_kit.masks.base import CameraInput
    from mamma_kit.masks.sam2 import Sam2Backend

    root, truth = video
    prompts = tmp_path / "prompts.toml"
    write_toml(prompts, {"cam0": [{"track": 5, "frame": 0, "box": [8, 18, 32, 72]},
                                  {"track": 9, "frame": 0, "box": [118, 28, 142, 82]}]})
    mt, _ = Sam2Backend(ckpt, cfg, prompts, chunk=8).track_camera(CameraInput("cam0", root / "videos" / "cam0.mp4",
                                                                               root))
    ious = [_iou(mt.mask(t, mt.track_column(k)), m) for (t, k), m in truth.items()
            if k in (5, 9) and mt.present[t, mt.track_column(k)]]
    assert np.mean(ious) > 0.8
    assert isinstance(mt, MaskTracks)
