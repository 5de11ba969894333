"""MammaNet inference: crops -> network -> image-space landmarks, and a whole workspace streamed.

``Predictor`` wraps a loaded model with the crop contract (crop.py):

>>> pred = Predictor(load_model())                      # embedded weights
>>> out = pred.predict_image(rgb_hw3, [mask_hw, ...])   # dict of (P, L, ...) arrays in image px

``run_camera`` streams one camera's video: a reader thread decodes frames and cuts the crops of every
(frame, track) with a non-empty mask into a bounded queue; the main thread batches them through the
network and hands each batch's rows to a sink (``DenseSink``: arrays in memory, for a short take;
the landmarks stage's sink streams them into the file). The keypoints it reads come a block of frames
at a time (``PointsByFrame``). Memory is one frame plus a few batches of crops, whatever the video
length.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Iterator

import cv2
import numpy as np
import torch
from rich.progress import BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn, TimeElapsedColumn, \
    TimeRemainingColumn
from rich.text import Text

from mamma_kit.core import log
from mamma_kit.core.errors import UserError
from mamma_kit.core.tracks import KeypointTracks, LandmarkTracks, MaskTracks
from mamma_kit.landmarks import crop as C
from mamma_kit.landmarks.prefetch import threaded
from mamma_kit.landmarks.weights import LoadedModel

MIN_MASK_AREA = 16  # px; (almost) empty masks are skipped as in the official pre-processing


class Predictor:
    def __init__(self, loaded: LoadedModel, device: str = "cpu"):
        self.loaded = loaded
        self.model = loaded.model.to(device).eval()
        self.cfg = loaded.config
        self.device = device
        H, W = self.cfg.input_hw
        self.out_wh = (W, H)

    @property
    def n_landmarks(self) -> int:
        return self.cfg.n_landmarks

    def crop(self, image_hw3: np.ndarray, mask_hw: np.ndarray | None = None, tight_box: np.ndarray | None = None):
        """(crop image, crop mask or None, crop box cx, cy, bw, bh) of one person; the box comes from the mask
        unless ``tight_box`` (x1, y1, x2, y2 min/max pixel indices) is given. None if the mask is empty."""
        if tight_box is None:
            if mask_hw is None:
                raise ValueError("need a mask or a box")
            tight_box = C.mask_box(mask_hw)
            if tight_box is None:
                return None
        box = C.expand_box(tight_box)
        img, m, _ = C.warp_crop(image_hw3, box, self.out_wh, mask_hw if self.cfg.use_mask else None,
                                rule=self.cfg.antialias)
        return img, m, box

    @property
    def needs_keypoints(self) -> bool:
        return self.cfg.keypoints_in > 0

    def crop_inputs(self, image_hw3: np.ndarray, box_n4: np.ndarray, keypoints_p5: np.ndarray | None = None,
                    others_hw: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The keypoint-guided inputs of one crop: ``keypoints`` (P, 5) (absent where None) and
        ``others`` (H_in, W_in) uint8, the other people's mask in the crop (empty where None)."""
        M = C.crop_affine(box_n4, self.out_wh)
        out = {}
        if self.cfg.keypoints_in:
            out["keypoints"] = np.zeros((self.cfg.keypoints_in, 5), np.float32) if keypoints_p5 is None \
                else C.crop_keypoints(keypoints_p5, M, self.out_wh)
        if self.cfg.others_in_stem:
            W, H = self.out_wh
            out["others"] = np.zeros((H, W), np.uint8) if others_hw is None or not others_hw.any() else \
                cv2.warpAffine(others_hw.astype(np.uint8), M, (W, H), flags=cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return out

    @torch.inference_mode()
    def predict_crops(self, crops_bhw3: np.ndarray, masks_bhw: np.ndarray | None = None,
                      keypoints_bp5: np.ndarray | None = None, others_bhw: np.ndarray | None = None
                      ) -> dict[str, np.ndarray]:
        """Network outputs for a batch of crops: xy_n (B, L, 2) in [-1, 1], log_sigma (B, L), and
        visibility / contact / floor_contact probabilities (B, L). ``keypoints_bp5`` / ``others_bhw``:
        the keypoint-guided inputs of ``crop_inputs`` (ignored by models that do not read them)."""
        x = C.normalise_images(crops_bhw3, self.device)
        m = C.mask_tensor(masks_bhw, self.device) if self.cfg.use_mask else None
        kp = torch.as_tensor(keypoints_bp5, device=self.device) if self.cfg.keypoints_in and keypoints_bp5 is not None \
            else None
        oth = C.mask_tensor(others_bhw, self.device) if self.cfg.others_in_stem and others_bhw is not None else None
        out = self.model(x, m, kp, oth)
        return {"xy_n": out["xy"].float().cpu().numpy(), "log_sigma": out["log_sigma"].float().cpu().numpy(),
                "visibility": torch.sigmoid(out["vis_logit"]).float().cpu().numpy(),
                "contact": torch.sigmoid(out["contact_logit"]).float().cpu().numpy(),
                "floor_contact": torch.sigmoid(out["floor_logit"]).float().cpu().numpy()}

    @staticmethod
    def to_image(net: dict[str, np.ndarray], boxes_b4: np.ndarray) -> dict[str, np.ndarray]:
        """Network outputs -> image px: xy (B, L, 2), sigma (B, L, 2) per axis, probabilities unchanged."""
        return {"xy": C.normalised_to_image(net["xy_n"], boxes_b4), "sigma": C.sigma_to_pixels(net["log_sigma"], boxes_b4),
                "visibility": net["visibility"], "contact": net["contact"], "floor_contact": net["floor_contact"]}

    def predict_image(self, image_hw3: np.ndarray, masks: list[np.ndarray],
                      keypoints: list[np.ndarray | None] | None = None) -> dict[str, np.ndarray]:
        """Landmarks in image px for each person mask of one image (persons with empty masks get NaN);
        ``keypoints``: each person's (P, 5) points in image px (keypoint-guided models)."""
        P, L = len(masks), self.n_landmarks
        out = {"xy": np.full((P, L, 2), np.nan), "sigma": np.full((P, L, 2), np.nan),
               "visibility": np.zeros((P, L)), "contact": np.zeros((P, L)), "floor_contact": np.zeros((P, L))}
        crops = [self.crop(image_hw3, m) for m in masks]
        keep = [i for i, c in enumerate(crops) if c is not None]
        if keep:
            extra = [self.crop_inputs(image_hw3, crops[i][2], keypoints[i] if keypoints else None,
                                      others_mask(masks, i)) for i in keep]
            net = self.predict_crops(np.stack([crops[i][0] for i in keep]),
                                     np.stack([crops[i][1] for i in keep]) if self.cfg.use_mask else None,
                                     *stack_extra(extra))
            res = self.to_image(net, np.stack([crops[i][2] for i in keep]))
            for key in out:
                out[key][keep] = res[key]
        return out


def others_mask(masks: list[np.ndarray | None], i: int) -> np.ndarray | None:
    """The union of every mask but the i-th (None when there is no other)."""
    rest = [m for j, m in enumerate(masks) if j != i and m is not None]
    return np.logical_or.reduce(rest) if rest else None


def stack_extra(extra: list[dict]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(keypoints (B, P, 5) or None, others (B, H, W) or None) from ``crop_inputs`` dicts."""
    if not extra:
        return None, None
    return tuple(np.stack([e[k] for e in extra]) if k in extra[0] else None for k in ("keypoints", "others"))


def track_points(kt: KeypointTracks, t: int, k: int) -> np.ndarray | None:
    """(P, 5) x, y, z, visibility, presence of track column k at frame t, None without a pose."""
    if not kt.valid[t, k]:
        return None
    return np.concatenate([kt.xy[t, k], kt.z[t, k, :, None], kt.visibility[t, k, :, None],
                           kt.presence[t, k, :, None]], 1)


class PointsByFrame:
    """``track_points`` of a camera's keypoints, from a KeypointTracks in memory or a keypoints file
    (core.trackrows.TrackFile) read a block of frames at a time, in increasing order."""

    BLOCK = 64
    KEYS = ("valid", "xy", "z", "visibility", "presence")

    def __init__(self, source):
        self.source = source
        self.frame_times, self.track_ids = source.frame_times, source.track_ids
        self._a, self._w = 0, source if isinstance(source, KeypointTracks) else None
        self._b = len(self.frame_times) if self._w is not None else 0

    def at(self, t: int, k: int) -> np.ndarray | None:
        if not self._a <= t < self._b:
            self._a, self._b = t, t + self.BLOCK
            self._w = self.source.window(self._a, self._b, keys=self.KEYS)
        return track_points(self._w, t - self._a, k)


class DenseSink:
    """Landmark rows gathered into a LandmarkTracks of the whole camera (a short take, the fill's tracks)."""

    def __init__(self, out: LandmarkTracks):
        self.out = out

    def add(self, t_n: np.ndarray, k_n: np.ndarray, cells: dict, complete_before: int) -> None:
        self.out.valid[t_n, k_n] = True
        for key, v in cells.items():
            getattr(self.out, key)[t_n, k_n] = v

    def finish(self) -> None:
        pass


# ---- progress with crops/s --------------------------------------------------------------------
class _RateColumn(ProgressColumn):
    def render(self, task) -> Text:
        speed = task.finished_speed or task.speed
        return Text(f"{speed:5.1f} crops/s" if speed else "  ... crops/s")


def _progress() -> Progress:
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), _RateColumn(),
                    TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=log.console,
                    disable=log.is_quiet() or not log.console.is_terminal, transient=True)


# ---- streaming one camera -------------------------------------------------------------------------
def mask_areas(mt: MaskTracks) -> np.ndarray:
    """(T, K) mask area px straight from the RLE runs (no decoding)."""
    counts = np.asarray(mt.rle_counts, np.int64)
    pos = np.arange(len(counts))
    # runs at odd offsets from their segment's start are foreground; split by global parity
    cs = [np.r_[0, np.cumsum(np.where(pos % 2 == par, counts, 0))] for par in (0, 1)]
    start, n = mt.rle_index[..., 0], mt.rle_index[..., 1]
    par = (start + 1) % 2
    a0 = cs[0][start + n] - cs[0][start]
    a1 = cs[1][start + n] - cs[1][start]
    return np.where(n > 0, np.where(par == 0, a0, a1), 0)


@dataclass
class _Job:
    t: int
    k: int
    image: np.ndarray
    mask: np.ndarray | None
    box: np.ndarray
    extra: dict
    hand: dict | None = None  # the frame, full masks and keypoints, for the hand refinement
    contact_crop: tuple | None = None  # (image, mask, box) cropped for the contact network
    alone: bool = False  # no other tracked person near in the frame: no person contact to see


# a person's box, grown by this share of its height, that meets no other tracked person's box: they
# touch nobody the camera tracks, and the contact network is not run on them (their person contact
# is 0). Touching people's boxes overlap in every view that sees both.
CONTACT_NEAR_SHARE = 0.1


def alone_in_frame(boxes_k4: np.ndarray, k: int, share: float = CONTACT_NEAR_SHARE) -> bool:
    """Whether box k (x1, y1, x2, y2; NaN rows absent), grown by ``share`` of its height, meets no other box."""
    b = boxes_k4[k]
    g = share * (b[3] - b[1])
    others = np.delete(boxes_k4, k, axis=0)
    others = others[np.isfinite(others).all(1)]
    meet = (others[:, 0] <= b[2] + g) & (others[:, 2] >= b[0] - g) & (others[:, 1] <= b[3] + g) & \
        (others[:, 3] >= b[1] - g)
    return not bool(meet.any())


def _crop_jobs(pred: Predictor, masks: MaskTracks, frames: Iterator[tuple[int, np.ndarray]],
               todo: np.ndarray, keypoints: PointsByFrame | None, hands: bool = False,
               contact: Predictor | None = None) -> Iterator[_Job]:
    boxes = C.tight_box_from_track_box(masks.boxes)
    guided = pred.needs_keypoints
    for t, img in frames:
        cols = np.flatnonzero(todo[t])
        # the other people's masks come from every track present in the frame, not only those cropped
        all_cols = np.flatnonzero(masks.present[t]) if guided or hands else cols
        mlist = {int(k): masks.mask(t, k) for k in all_cols}
        for k in cols:
            m = mlist[int(k)]
            tb = boxes[t, k] if np.all(np.isfinite(boxes[t, k])) else C.mask_box(m)
            res = pred.crop(img, m, tb)
            if res is None:
                continue
            extra, hand = {}, None
            if guided or hands:
                keys = list(mlist)
                others = others_mask([mlist[j] for j in keys], keys.index(int(k)))
                points = keypoints.at(t, k) if keypoints else None
                if guided:
                    extra = pred.crop_inputs(img, res[2], points, others)
                if hands:
                    hand = {"image": img, "mask": m, "tight_box": tb, "keypoints": points, "others": others}
            alone = contact is not None and alone_in_frame(masks.boxes[t], int(k))
            yield _Job(int(t), int(k), res[0], res[1], res[2], extra, hand,
                       contact.crop(img, m, tb) if contact is not None and not alone else None, alone)


def run_camera(pred: Predictor, cam: str, masks: MaskTracks, video_path, batch: int = 8,
               min_area: int = MIN_MASK_AREA, producer: dict | None = None,
               keypoints=None, frame_range: tuple[int, int] | None = None,
               hands=None, contact: Predictor | None = None, rotation: int | None = None, sink=None
               ) -> tuple[LandmarkTracks | None, dict]:
    """Landmarks for every (frame, track) of one camera with a non-empty mask, streaming the video.
    ``hands``: a hands.HandRefiner that re-reads each hand at the frame's resolution. ``contact``: a
    second network (its own crops) whose person-contact head replaces ``pred``'s, run only on people
    near another tracked person (``alone_in_frame``: the others' person contact is 0).
    ``keypoints``: the camera's keypoints (a KeypointTracks, or its file as a core.trackrows.TrackFile;
    on the mask tracks' frames and tracks), which keypoint-guided models read. ``frame_range``: only the
    mask frames start:stop (a unit of a split camera; every crop is independent of the others, so the
    split changes nothing). ``rotation``: capture.toml's override of the file's display rotation.
    ``sink``: where each batch's rows go (``add(frame_n, track_n, cells, complete_before)``, then
    ``finish()``); None gathers them into the LandmarkTracks returned (else None is returned)."""
    from mamma_kit.core.tracks import nearest_frames
    from mamma_kit.video import VideoReader

    reader = VideoReader(video_path, rotation)
    if tuple(reader.size) != tuple(masks.image_size):
        raise UserError(f"masks/{cam}.npz is {masks.image_size[0]}x{masks.image_size[1]} but {reader.path.name} is "
                        f"{reader.size[0]}x{reader.size[1]}", "run `mamma-kit track` again for this camera")
    if keypoints is not None and (len(keypoints.frame_times) != len(masks.frame_times)
                                  or not np.array_equal(keypoints.track_ids, masks.track_ids)):
        raise UserError(f"keypoints/{cam}.npz does not belong to masks/{cam}.npz (other frames or tracks)",
                        "run `mamma-kit keypoints` again for this camera")
    todo = masks.present & (mask_areas(masks) >= min_area)
    if frame_range is not None:
        todo[:frame_range[0]] = False
        todo[frame_range[1]:] = False
    vid_idx = nearest_frames(masks.frame_times, reader.timestamps)
    lost = int((todo.any(1) & (vid_idx < 0)).sum())
    if lost:
        log.warn(f"{cam}: {lost} mask frames have no video frame at their time; they are skipped")
    todo &= (vid_idx >= 0)[:, None]
    total = int(todo.sum())
    by_video = {int(v): int(t) for t, v in enumerate(vid_idx) if v >= 0 and todo[t].any()}

    def frames():
        for i, _, img in reader.read_indices(sorted(by_video)):
            yield by_video[i], img

    out = None
    if sink is None:
        out = LandmarkTracks.empty(cam, masks.image_size, masks.frame_times, masks.track_ids, pred.n_landmarks,
                                   pred.loaded.landmark_set, f"mammanet:{pred.cfg.name}")
        out.producer = producer or {}
        sink = DenseSink(out)
    points = None if keypoints is None else PointsByFrame(keypoints)
    t0 = time.perf_counter()
    pending: list[_Job] = []

    def flush():
        if not pending:
            return
        net = pred.predict_crops(np.stack([j.image for j in pending]),
                                 np.stack([j.mask for j in pending]) if pred.cfg.use_mask else None,
                                 *stack_extra([j.extra for j in pending] if pred.needs_keypoints else []))
        res = Predictor.to_image(net, np.stack([j.box for j in pending]))
        if hands is not None:
            people = [{**j.hand, "xy": res["xy"][i], "sigma": res["sigma"][i], "visibility": res["visibility"][i]}
                      for i, j in enumerate(pending)]
            hands.refine(people)  # writes into res's rows
        if contact is not None:
            cc = [j.contact_crop for j in pending]
            keep = [i for i, c in enumerate(cc) if c is not None]
            if keep:
                net_c = contact.predict_crops(np.stack([cc[i][0] for i in keep]),
                                              np.stack([cc[i][1] for i in keep]) if contact.cfg.use_mask else None)
                res["contact"][keep] = net_c["contact"]
            res["contact"][[i for i, j in enumerate(pending) if j.alone]] = 0.0
        ti = np.array([j.t for j in pending])
        ki = np.array([j.k for j in pending])
        # the next job's frame is at or after the last one's: the frames before that are complete
        sink.add(ti, ki, {key: res[key] for key in ("xy", "sigma", "visibility", "contact", "floor_contact")},
                 complete_before=int(ti[-1]))
        pending.clear()

    done = 0
    with _progress() as bar:
        task = bar.add_task(f"landmarks {cam}" + (f" {frame_range[0]}-{frame_range[1]}" if frame_range else ""), total=total)
        for job in threaded(lambda: _crop_jobs(pred, masks, frames(), todo, points, hands is not None, contact),
                            maxsize=2 * batch):
            pending.append(job)
            if len(pending) >= batch:
                n = len(pending)
                flush()
                done += n
                bar.advance(task, n)
        n = len(pending)
        flush()
        done += n
        bar.advance(task, n)
    sink.finish()
    secs = time.perf_counter() - t0
    summary = {"camera": cam, "crops": done, "frames": int(todo.any(1).sum()), "tracks": int(len(masks.track_ids)),
               "seconds": round(secs, 3), "crops_per_s": round(done / secs, 2) if secs > 0 else None}
    log.info(f"{cam}: {done} crops in {secs:.1f} s ({summary['crops_per_s']} crops/s)")
    return out, summary
