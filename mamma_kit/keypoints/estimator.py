"""BlazePose on frames: people found by the detector, 33 points and a mask per person.

``PoseEstimator`` holds the two LiteRT models. Everything it returns is in image pixels:

>>> est = PoseEstimator()
>>> dets = est.detect(rgb_hw3)                      # Detections: boxes (N, 4), points (N, 4, 2), scores
>>> rois = est.rois_from_detections(dets)           # (N, 4) cx, cy, side, rotation
>>> res = est.landmarks(rgb_hw3, rois)              # PoseResult: xy (N, 33, 2), visibility, presence, ...
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mamma_kit.keypoints import blazepose as bp
from mamma_kit.keypoints.runtime import DETECTOR, LANDMARKER, TfliteModel

# a detection region (a track's box) is widened by this much before the detector sees it: the
# detector expects the whole body with some context
REGION_MARGIN = 1.5
# the landmark model's pose flag below this means "no person in this ROI" for a new person; a person
# already followed (its own ROI, its own mask) is kept down to the lower flag: partly hidden people
# score 0.1-0.5 on the real recording while their points still land on them
MIN_POSE_FLAG = 0.5
MIN_FOLLOW_FLAG = 0.2
# a person's mask is grown by this share of the model's input before the rest is blanked: masks from
# a tracker miss thin limbs and rims, and a cut-off hand is worse than a little background (on the
# real 4-camera recording, triangulated points reproject at a median 2.6 % of the box height unmasked,
# 2.7 % grown by 0.03, 2.4 % by 0.08, 2.6 % by 0.15)
MASK_GROW = 0.08


def warp_masked(image_hw3: np.ndarray, mask_hw: np.ndarray | None, A_23: np.ndarray, size: int) -> np.ndarray:
    """The image warped by A_23 to (size, size, 3) uint8; with a mask, pixels outside the (grown)
    mask are black. Warping first keeps the cost at the input's size, not the frame's."""
    flags = cv2.INTER_AREA if np.linalg.norm(A_23[:, 0]) < 1 else cv2.INTER_LINEAR
    x = cv2.warpAffine(image_hw3, A_23, (size, size), flags=flags, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=(0, 0, 0))
    if mask_hw is not None:
        m = cv2.warpAffine(mask_hw.astype(np.uint8), A_23, (size, size), flags=cv2.INTER_NEAREST,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        r = max(1, int(round(MASK_GROW * size)))
        m = cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
        x *= m[..., None]
    return x


@dataclass
class Detections:
    boxes: np.ndarray  # (N, 4) x1 y1 x2 y2 px
    points: np.ndarray  # (N, 4, 2) px: hip centre, scale point, shoulder centre, upper-body point
    scores: np.ndarray  # (N,)

    def __len__(self) -> int:
        return len(self.scores)


@dataclass
class PoseResult:
    xy: np.ndarray  # (N, 33, 2) px
    z: np.ndarray  # (N, 33) depth relative to the hips, px-scaled
    visibility: np.ndarray  # (N, 33) in [0, 1]
    presence: np.ndarray  # (N, 33) in [0, 1]
    score: np.ndarray  # (N,) the pose flag
    next_rois: np.ndarray  # (N, 4) the ROI for the next frame, from the auxiliary points
    rois: np.ndarray  # (N, 4) the ROIs these came from
    segmentation: list  # N x (prob (h, w) float32, (x0, y0)) when asked, else []
    seg_logits: np.ndarray | None = None  # (N, 256, 256) the model's segmentation logits of each ROI
    affines: np.ndarray | None = None  # (N, 2, 3) image px -> ROI input px

    def segmentation_of(self, n: int, image_wh: tuple[int, int]) -> tuple[np.ndarray, tuple[int, int]]:
        """ROI n's segmentation probability on the image: (prob (h, w) over its box, (x0, y0))."""
        return bp.segmentation_to_image(self.seg_logits[n], self.affines[n], image_wh)


class PoseEstimator:
    def __init__(self, threads: int | None = None):
        self.detector = TfliteModel(DETECTOR, threads)
        self.landmarker = TfliteModel(LANDMARKER, threads)

    # ---- detection ------------------------------------------------------------------------------
    def detect_batch(self, inputs_b: np.ndarray, affines_b23: np.ndarray, min_score: float = bp.MIN_DET_SCORE
                     ) -> list[Detections]:
        """Detector on prepared inputs (B, 224, 224, 3); ``affines_b23`` map image px -> input px."""
        raw, logits = (bp.unfold_detector_batch(y, len(inputs_b)) for y in self.detector.run(inputs_b))
        out = []
        for b in range(len(inputs_b)):
            boxes, kps, scores = bp.weighted_nms(*bp.decode_detections(raw[b], logits[b], min_score))
            inv = bp.invert_affine(affines_b23[b])
            if len(scores):
                corners = np.stack([boxes[:, [0, 1]], boxes[:, [2, 1]], boxes[:, [0, 3]], boxes[:, [2, 3]]], 1)
                img_c = bp.apply_affine(inv, corners.reshape(-1, 2)).reshape(-1, 4, 2)
                boxes = np.concatenate([img_c.min(1), img_c.max(1)], 1)
                kps = bp.apply_affine(inv, kps.reshape(-1, 2)).reshape(kps.shape)
            out.append(Detections(boxes, kps, scores))
        return out

    def detect(self, image_hw3: np.ndarray, min_score: float = bp.MIN_DET_SCORE) -> Detections:
        """People in the whole frame (letterboxed to the detector's input)."""
        x, A = bp.letterbox(image_hw3)
        return self.detect_batch(x[None], A[None], min_score)[0]

    def detect_regions(self, image_hw3: np.ndarray, boxes_n4: np.ndarray, masks: list | None = None,
                       min_score: float = bp.MIN_DET_SCORE, margin: float = REGION_MARGIN) -> list[Detections]:
        """The detector on square regions around each box (widened by ``margin``). With ``masks``
        (bool (H, W) or None per box) the pixels outside a box's mask are blanked, so the detector
        sees only that person where two overlap."""
        size = bp.DET_SIZE
        inputs, affines = [], []
        for i, box in enumerate(np.asarray(boxes_n4, np.float64)):
            cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
            side = max(box[2] - box[0], box[3] - box[1]) * margin
            A = bp.roi_affine(np.array([cx, cy, side, 0.0]), size)
            x = warp_masked(image_hw3, masks[i] if masks is not None else None, A, size)
            inputs.append(x.astype(np.float32) * (2.0 / 255.0) - 1.0)
            affines.append(A)
        if not inputs:
            return []
        return self.detect_batch(np.stack(inputs), np.stack(affines), min_score)

    @staticmethod
    def rois_from_detections(dets: Detections) -> np.ndarray:
        return bp.roi_from_points(dets.points[:, 0], dets.points[:, 1])

    def rois_for_boxes(self, image_hw3: np.ndarray, boxes_n4: np.ndarray, masks: list | None = None) -> np.ndarray:
        """(N, 4) an ROI for the person in each box: the detector on the box's region (the rest
        blanked by its mask), the detection nearest the box's centre (the box's person, not a
        neighbour); where it finds none, the box itself, upright, covering its longer side."""
        boxes_n4 = np.asarray(boxes_n4, np.float64).reshape(-1, 4)
        rois = np.zeros((len(boxes_n4), 4))
        for j, (box, d) in enumerate(zip(boxes_n4, self.detect_regions(image_hw3, boxes_n4, masks))):
            if len(d):
                c = (box[:2] + box[2:]) / 2
                best = int(np.argmin(np.linalg.norm(d.points[:, 0] - c, axis=1) - 1e3 * d.scores))
                rois[j] = self.rois_from_detections(d)[best]
            else:
                w, h = box[2] - box[0], box[3] - box[1]
                rois[j] = [(box[0] + box[2]) / 2, (box[1] + box[3]) / 2, 1.15 * max(w, h), 0.0]
        return rois

    def person_points(self, image_hw3: np.ndarray, box_4: np.ndarray, mask_hw: np.ndarray | None = None
                      ) -> np.ndarray:
        """(33, 5) x, y px, z, visibility, presence of the one person in ``box`` (NaN where the pose
        flag is below MIN_FOLLOW_FLAG): found as where a track starts, then run once more on the
        ROI its own points give, as on the frames after (training inputs that match the stage's)."""
        masks = None if mask_hw is None else [mask_hw]
        res = self.landmarks(image_hw3, self.rois_for_boxes(image_hw3, box_4, masks), masks=masks)
        if res.score[0] >= MIN_FOLLOW_FLAG:
            res = self.landmarks(image_hw3, res.next_rois, masks=masks)
        out = np.full((bp.N_POINTS, 5), np.nan, np.float32)
        if res.score[0] >= MIN_FOLLOW_FLAG:
            out[:, :2], out[:, 2], out[:, 3], out[:, 4] = res.xy[0], res.z[0], res.visibility[0], res.presence[0]
        return out

    # ---- landmarks --------------------------------------------------------------------------------
    def landmarks(self, image_hw3: np.ndarray, rois_n4: np.ndarray, segmentation: bool = False,
                  masks: list | None = None) -> PoseResult:
        """33 points for each ROI of one frame (batched). ``masks``: optional bool (H, W) per ROI; the
        ROI's pixels outside it (grown by MASK_GROW) are blanked: the person alone."""
        rois_n4 = np.asarray(rois_n4, np.float64).reshape(-1, 4)
        crops, affines = [], []
        for i, roi in enumerate(rois_n4):
            A = bp.roi_affine(roi, bp.LMK_SIZE)
            x = warp_masked(image_hw3, masks[i] if masks is not None else None, A, bp.LMK_SIZE)
            crops.append(x.astype(np.float32) * (1.0 / 255.0))
            affines.append(A)
        if not crops:
            e = np.zeros((0, bp.N_POINTS))
            return PoseResult(np.zeros((0, bp.N_POINTS, 2)), e, e, e, np.zeros(0), np.zeros((0, 4)),
                              rois_n4, [])
        return self.landmarks_batch(np.stack(crops), np.stack(affines), rois_n4, image_hw3.shape[1::-1]
                                    if segmentation else None)

    def landmarks_batch(self, crops_b: np.ndarray, affines_b23: np.ndarray, rois_b4: np.ndarray,
                        image_wh: tuple[int, int] | None = None) -> PoseResult:
        """The landmark model on prepared crops; ``image_wh`` asks for the masks on the image."""
        raw, flag, seg, heat, _world = self.landmarker.run(crops_b)
        dec = bp.decode_landmarks(raw, heat, affines_b23)
        P = bp.N_POINTS
        nxt = bp.roi_from_points(dec["xy"][:, P], dec["xy"][:, P + 1])
        segs = [bp.segmentation_to_image(seg[b, ..., 0], affines_b23[b], image_wh) for b in range(len(crops_b))] \
            if image_wh is not None else []
        return PoseResult(dec["xy"][:, :P], dec["z"][:, :P], dec["visibility"][:, :P], dec["presence"][:, :P],
                          np.asarray(flag, np.float64).reshape(-1), nxt, rois_b4, segs, seg[..., 0], affines_b23)
