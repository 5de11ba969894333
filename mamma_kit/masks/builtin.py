"""`--backend builtin`: person mask tracks without any weights, for static cameras.

Per camera:

1. Background model: the per-pixel median over frames sampled across the video, then again
   over the samples where that pixel was not foreground (a person standing still for a third
   of the video does not end up in the background). Per-pixel noise from the background samples'
   median absolute deviation. When the camera has a board video (the calibration session, shot
   from the same place), its median is a clean plate: used when it agrees with the capture's
   own background (``plate_background``), so people who never move are still foreground.
2. Foreground in a shadow-robust colour model: each pixel's colour is compared with the
   background as a brightness ratio alpha = <I, B> / <B, B> and a chromatic distortion
   |I - alpha B| (Horprasert-style). A soft shadow darkens the background without changing
   its chromaticity (0.45 < alpha < 1, small distortion): background. Then opening/closing,
   hole filling (for tracking; the masks written keep large holes open: floor seen between two
   people), a rim pass (``refine_rim``: a blurred or chroma-subsampled edge pixel is the
   person's only if it covers at least half of it) and connected components above a minimum area.
3. Tracking: each track's last mask, shifted by its velocity, predicts where it is. A component
   claimed by two or more predictions (people touching or crossing) is split pixel by pixel
   between them by distance to each prediction and each track's colour histogram (colour
   evidence averaged over a small neighbourhood, so the cut follows regions, not single pixels); a track
   that gets (almost) nothing is occluded and coasts on its velocity. A track that alone claims a
   component (its person seen whole) takes no share of another (where it was while hidden). A
   track holding two person-like pieces side by side lets go of the one its prediction covers
   least (two people who came in together, or walked a few pixels apart); if the head count is
   full, two tracks lying one above the other (one person's top and legs) are joined to make room.
   Components no prediction
   claims are matched to recently lost tracks by appearance and position (Hungarian), else
   start new tracks. A new track that parted from another (the previous frame's mask of that
   track held it: two people who came in as one blob) is followed back in time
   (``tracker.split_back``, up to ``backfill_frames``) and the blob they shared is split between
   them there too, so neither person is missing, nor the other's body given to one, until they
   part. Tracks lost for more than ``max_lost`` frames end; a person who comes back later gets a new track (cross-view matching rejoins it with its person).

Work happens at a reduced resolution (``max_side``) and masks are scaled back to the video's.
Where it struggles (benchmarks/masks_quality.py): people who never move (background), clothes
the colour of the background, and long full occlusions.

The pieces: builtin_settings.py (the numbers), segment.py (steps 1 and 2, per pixel),
tracker.py (step 3, per frame); this module reads the video and puts them together.
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

from mamma_kit.core import log
from mamma_kit.core.tracks import MaskTracks
from mamma_kit.masks.base import CameraInput, MaskTrackBuilder, track_summary
from mamma_kit.masks.builtin_settings import BuiltinSettings
from mamma_kit.masks.segment import (Background, build_background, colour_index, denoise, enclosed, foreground,
                                     larger_than, plate_background, refine_rim)
from mamma_kit.masks.tracker import Tracker, parted_from, split_back

__all__ = ["BuiltinBackend", "BuiltinSettings", "load_settings"]


class BuiltinBackend:
    name = "builtin"

    def __init__(self, settings: BuiltinSettings | None = None):
        self.s = settings or BuiltinSettings()

    def _plate(self, cam: CameraInput, capture_bg: Background, prep, size_wh) -> tuple[Background, dict]:
        """The board video's clean plate, or the capture's own background with the reason why not."""
        from mamma_kit.video.reader import VideoReader

        s = self.s
        rd = VideoReader(cam.board_video, cam.rotation)
        W, H = size_wh
        bw, bh = rd.size
        if abs(bw / bh - W / H) > 0.01:
            info = {"source": "capture median", "plate": f"board video is {bw}x{bh}, the capture {W}x{H}"}
            log.warn(f"{cam.name}: {info['plate']}: background from the capture itself")
            return capture_bg, info
        n = rd.n_frames
        idx = np.unique(np.round(np.linspace(0, n - 1, min(s.bg_samples, n))).astype(int))
        frames = [prep(img if (bw, bh) == (W, H) else cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA))
                  for _, _, img in rd.read_indices(idx)]
        plate, info = plate_background(frames, capture_bg, s)
        if plate is None:
            log.warn(f"{cam.name}: the board video's scene differs from the capture's on {info['plate_differs']:.0%} "
                     "of the image (camera moved or light changed): background from the capture itself")
            return capture_bg, {"source": "capture median", **info}
        return plate, {"source": "board video", **info}

    def track_camera(self, cam: CameraInput) -> tuple[MaskTracks, dict]:
        from mamma_kit.video.reader import VideoReader

        s = self.s
        rd = VideoReader(cam.video, cam.rotation)
        times = rd.timestamps
        W, H = rd.size
        f = min(1.0, s.max_side / max(W, H))
        ws_ = (max(1, int(round(W * f))), max(1, int(round(H * f))))

        def prep(img):
            return img if f == 1.0 else cv2.resize(img, ws_, interpolation=cv2.INTER_AREA)

        n = len(times)
        idx = np.unique(np.round(np.linspace(0, n - 1, min(s.bg_samples, n))).astype(int))
        samples = [prep(img) for _, _, img in rd.read_indices(idx)]
        bg = build_background(samples, s)
        del samples
        bg_info: dict = {"source": "capture median"}
        if cam.board_video is not None and s.use_board_plate:
            bg, bg_info = self._plate(cam, bg, prep, (W, H))
        tracker = Tracker((ws_[1], ws_[0]), s)
        out_tracks = MaskTrackBuilder(cam.name, (W, H), times)
        # the last frames' inputs (bit-packed), for a split carried back in time (tracker.split_back)
        recent: deque = deque(maxlen=max(s.backfill_frames, 0))
        prev: dict = {}
        backfilled = 0

        def emit(ti: int, k: int, m: np.ndarray, sc: float, gaps) -> None:
            if gaps is not None:
                m = m & ~gaps
            if f != 1.0:
                m = cv2.resize(m.astype(np.uint8) * 255, (W, H), interpolation=cv2.INTER_LINEAR) > 127
            out_tracks.add(ti, k, m, sc)

        shape = (ws_[1], ws_[0])
        unpack = (lambda b: None if b is None else np.unpackbits(b, count=shape[0] * shape[1]).reshape(shape) > 0)
        for t, img in log.track(rd.frames(), f"track {cam.name}", total=n):
            ti = int(np.argmin(np.abs(times - t)))
            small = prep(img)
            dn = denoise(foreground(small, bg, s), small.shape[0])
            holes = enclosed(dn)
            # tracking sees people with their holes filled (clothes of the background's colour);
            # the masks written keep the large holes open: floor seen between two people or
            # between someone's legs, enclosed by limbs and shadows
            gaps = larger_than(holes, int(s.max_hole_frac * dn.size)) if s.max_hole_frac > 0 else None
            fg = dn | holes
            if s.edge_coverage > 0:
                fg = refine_rim(fg, small, bg, s)
            cidx = colour_index(small)
            out = tracker.step(ti, fg, cidx)
            for k, (m, sc) in out.items():
                emit(ti, k, m, sc, gaps)
            # a new track that parted from another: the frames before, when they were one blob, split
            born = [k for k in out if k >= tracker.next_id_at_frame_start] if recent else []
            for k_new in born:
                k_old = parted_from(k_new, out, prev)
                if k_old is None:
                    continue
                # unpacked lazily: split_back usually stops long before the buffer's oldest frame
                earlier = ((tj, unpack(fj), cj.astype(np.int32)) for tj, fj, cj, _ in reversed(recent))
                fixed = split_back({k_old: out[k_old][0], k_new: out[k_new][0]}, cidx, earlier, s)
                for tj, _, _, gj in recent:
                    for k, (m, sc) in fixed.get(tj, {}).items():
                        emit(tj, k, m, sc, unpack(gj))
                backfilled += len(fixed)
            if recent.maxlen:
                recent.append((ti, np.packbits(fg), cidx.astype(np.uint16),
                               None if gaps is None else np.packbits(gaps)))
            prev = out
        mt = out_tracks.build()
        summ = track_summary(mt)
        summ["working_size"] = list(ws_)
        summ["backfilled_frames"] = backfilled  # frames where two tracks that parted later were split
        summ["background"] = bg_info
        summ["settings"] = asdict(s)
        return mt, summ


def load_settings(path: Path | None, overrides: dict | None = None) -> BuiltinSettings:
    s = BuiltinSettings()
    for k, v in (overrides or {}).items():
        if hasattr(s, k):
            setattr(s, k, type(getattr(s, k))(v))
    return s
