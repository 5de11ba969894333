"""BlazePose's pre- and post-processing as pure numpy functions (our own, from the model's facts).

Coordinates: image pixels with the OpenCV convention (integer = pixel centre). A region of interest
(ROI) is a rotated square: centre (x, y) px, side px, rotation rad (0 = the person upright; the
image direction of the ROI's "up" is Rot(rotation) @ (0, -1), y down).

Facts of the two models (BlazePose GHUM 3D full, from MediaPipe's graphs):
- detector: 224x224 RGB in [-1, 1], the frame letterboxed; 2254 SSD anchors (strides 8, 16, 32,
  32, 32; 2 anchors per cell at 28x28 and 14x14, 6 at 7x7; fixed size 1); 12 values per anchor:
  box centre offset, box size and 4 keypoints (0 hip centre, 1 a point whose distance from the hip
  centre is the radius of the body's circle, 2 shoulder centre, 3 the upper body's point), in
  input pixels; score logits clipped at +-100, kept at >= 0.5; weighted NMS at IoU 0.3.
- landmark model: 256x256 RGB in [0, 1] of the ROI; 39 points x (x, y, z, visibility, presence)
  in input pixels (33 body points, then 33/34 = the ROI's centre and scale points for the next
  frame); visibility and presence are logits; a pose flag; a 256x256 segmentation logit map; 64x64
  heatmaps of the 39 points.
- ROI from two alignment points (hip centre c, scale point s): rotation pi/2 - atan2(-(s_y - c_y),
  s_x - c_x), side 2 |s - c| x 1.25.
"""

from __future__ import annotations

import cv2
import numpy as np

DET_SIZE = 224
LMK_SIZE = 256
N_POINTS = 33
SCORE_CLIP = 100.0
MIN_DET_SCORE = 0.5
NMS_IOU = 0.3
ROI_SCALE = 1.25
HEATMAP_KERNEL = 7
HEATMAP_MIN_CONFIDENCE = 0.5

# the 33 BlazePose points, in the model's order
POINT_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
    "right_ankle", "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)
# bones for pictures and for telling which person a pixel belongs to
SKELETON = ((11, 12), (11, 13), (13, 15), (12, 14), (14, 16), (11, 23), (12, 24), (23, 24), (23, 25),
            (25, 27), (24, 26), (26, 28), (27, 29), (29, 31), (28, 30), (30, 32), (15, 19), (16, 20),
            (0, 11), (0, 12))


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(np.asarray(x, np.float64), -SCORE_CLIP, SCORE_CLIP)))


# ---- detector ----------------------------------------------------------------------------------
def ssd_anchors(size: int = DET_SIZE, strides=(8, 16, 32, 32, 32)) -> np.ndarray:
    """(A, 2) anchor centres in [0, 1] (x, y), in the detector's output order (A = 2254)."""
    out, i = [], 0
    while i < len(strides):
        # layers that share a stride share a grid: 2 anchors per layer (aspect 1 and the interpolated one)
        j = i
        while j < len(strides) and strides[j] == strides[i]:
            j += 1
        n = int(np.ceil(size / strides[i]))
        ys, xs = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n, indexing="ij")
        cells = np.stack([xs.ravel(), ys.ravel()], 1)
        out.append(np.repeat(cells, 2 * (j - i), axis=0))
        i = j
    return np.concatenate(out).astype(np.float64)


ANCHORS_A2 = ssd_anchors()
# anchors per grid (28x28x2, 14x14x2, 7x7x6): a batch of B inputs comes out grid by grid, each
# grid holding all B inputs' anchors, so the batch is unfolded grid by grid
ANCHOR_GRIDS = (1568, 392, 294)


def unfold_detector_batch(y_1n: np.ndarray, batch: int) -> np.ndarray:
    """The detector's (1, B * 2254, D) output -> (B, 2254, D) in ssd_anchors' order."""
    y = y_1n.reshape(-1, y_1n.shape[-1])
    parts, o = [], 0
    for n in ANCHOR_GRIDS:
        parts.append(y[o:o + batch * n].reshape(batch, n, -1))
        o += batch * n
    return np.concatenate(parts, 1)


def letterbox(image_hw3: np.ndarray, size: int = DET_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """Frame -> (size, size, 3) float32 in [-1, 1] with the frame's aspect kept, and A_23 mapping
    image px -> input px (both pixel-centre coordinates)."""
    h, w = image_hw3.shape[:2]
    s = size / max(w, h)
    ox, oy = (size - w * s) / 2, (size - h * s) / 2
    # continuous coordinates: q = s p_edge + o; pixel centres are edges - 0.5
    A = np.array([[s, 0, ox + 0.5 * s - 0.5], [0, s, oy + 0.5 * s - 0.5]], np.float64)
    x = cv2.warpAffine(image_hw3, A, (size, size), flags=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
    return x.astype(np.float32) * (2.0 / 255.0) - 1.0, A


def invert_affine(A_23: np.ndarray) -> np.ndarray:
    return cv2.invertAffineTransform(np.asarray(A_23, np.float64))


def apply_affine(A_23: np.ndarray, xy_n2: np.ndarray) -> np.ndarray:
    return xy_n2 @ A_23[:, :2].T + A_23[:, 2]


def decode_detections(raw_a12: np.ndarray, logits_a1: np.ndarray, min_score: float = MIN_DET_SCORE,
                      size: int = DET_SIZE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One input's raw outputs -> (boxes (N, 4) x1 y1 x2 y2, keypoints (N, 4, 2), scores (N,)) in
    input pixels (pixel-centre), for anchors scoring at least ``min_score``, before suppression."""
    scores = sigmoid(logits_a1[:, 0].astype(np.float64))
    keep = np.flatnonzero(scores >= min_score)
    r = raw_a12[keep].astype(np.float64) / size
    anc = ANCHORS_A2[keep]
    cx, cy = r[:, 0] + anc[:, 0], r[:, 1] + anc[:, 1]
    w, h = r[:, 2], r[:, 3]
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], 1) * size - 0.5
    kps = (r[:, 4:12].reshape(-1, 4, 2) + anc[:, None, :]) * size - 0.5
    return boxes, kps, scores[keep]


def box_iou(a_n4: np.ndarray, b_m4: np.ndarray) -> np.ndarray:
    """(..., N, M) IoU of x1 y1 x2 y2 boxes (any leading dims shared by both); 0 where a box is NaN."""
    lt = np.maximum(a_n4[..., :, None, :2], b_m4[..., None, :, :2])
    rb = np.minimum(a_n4[..., :, None, 2:], b_m4[..., None, :, 2:])
    inter = np.prod(np.clip(rb - lt, 0, None), axis=-1)
    area = lambda b: np.prod(np.clip(b[..., 2:] - b[..., :2], 0, None), axis=-1)  # noqa: E731
    return np.nan_to_num(inter / np.maximum(area(a_n4)[..., :, None] + area(b_m4)[..., None, :] - inter, 1e-12))


def weighted_nms(boxes_n4: np.ndarray, kps_nk2: np.ndarray, scores_n: np.ndarray, iou: float = NMS_IOU):
    """MediaPipe's weighted suppression: each cluster (IoU > ``iou`` with its best box) becomes the
    score-weighted mean of its boxes and keypoints, with the best score. Best first."""
    order = np.argsort(-scores_n)
    boxes_n4, kps_nk2, scores_n = boxes_n4[order], kps_nk2[order], scores_n[order]
    alive = np.ones(len(scores_n), bool)
    out_b, out_k, out_s = [], [], []
    ious = box_iou(boxes_n4, boxes_n4)
    for i in range(len(scores_n)):
        if not alive[i]:
            continue
        members = alive & (ious[i] > iou)
        members[i] = True
        wts = scores_n[members][:, None]
        out_b.append((boxes_n4[members] * wts).sum(0) / wts.sum())
        out_k.append((kps_nk2[members] * wts[:, :, None]).sum(0) / wts.sum())
        out_s.append(scores_n[i])
        alive &= ~members
    if not out_s:
        return np.zeros((0, 4)), np.zeros((0, kps_nk2.shape[1], 2)), np.zeros(0)
    return np.array(out_b), np.array(out_k), np.array(out_s)


# ---- regions of interest --------------------------------------------------------------------------
def roi_from_points(centre_n2: np.ndarray, scale_n2: np.ndarray, scale: float = ROI_SCALE) -> np.ndarray:
    """(N, 4) ROIs (cx, cy, side, rotation) from alignment points (hip centre, scale point), px."""
    d = scale_n2 - centre_n2
    rot = np.pi / 2 - np.arctan2(-d[:, 1], d[:, 0])
    rot = (rot + np.pi) % (2 * np.pi) - np.pi
    side = 2.0 * np.linalg.norm(d, axis=1) * scale
    return np.column_stack([centre_n2, side, rot])


def roi_affine(roi_4: np.ndarray, size: int = LMK_SIZE) -> np.ndarray:
    """A_23 mapping image px -> the ROI's input px (pixel-centre coordinates both sides)."""
    cx, cy, side, rot = (float(v) for v in roi_4)
    c, s = np.cos(rot), np.sin(rot)
    k = size / side
    # input q (continuous, centre at size/2) = k Rot(-rot) (p - centre) + size/2, shifted to pixel centres
    A = np.array([[k * c, k * s, 0.0], [-k * s, k * c, 0.0]])
    A[:, 2] = -A[:, :2] @ np.array([cx, cy]) + size / 2 - 0.5
    return A


def crop_roi(image_hw3: np.ndarray, roi_4: np.ndarray, size: int = LMK_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """The ROI as (size, size, 3) float32 in [0, 1] and its A_23 (image px -> input px)."""
    A = roi_affine(roi_4, size)
    x = cv2.warpAffine(image_hw3, A, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=(0, 0, 0))
    return x.astype(np.float32) * (1.0 / 255.0), A


# ---- landmarks ---------------------------------------------------------------------------------------
def refine_with_heatmap(xy_bp2: np.ndarray, heat_bhwp: np.ndarray, size: int = LMK_SIZE,
                        kernel: int = HEATMAP_KERNEL, min_conf: float = HEATMAP_MIN_CONFIDENCE) -> np.ndarray:
    """Points (input px) moved to the confidence-weighted mean of their heatmap window where the
    window's peak confidence reaches ``min_conf`` (as MediaPipe refines BlazePose's points)."""
    B, Hh, Wh, P = heat_bhwp.shape
    conf = sigmoid(heat_bhwp.astype(np.float64))
    g = (xy_bp2 + 0.5) * (Wh / size)  # heatmap continuous coords
    ci = np.clip(np.floor(g).astype(int), 0, Wh - 1)
    off = np.arange(kernel) - kernel // 2
    xs = np.clip(ci[..., 0:1] + off, 0, Wh - 1)  # (B, P, k)
    ys = np.clip(ci[..., 1:2] + off, 0, Hh - 1)
    b = np.arange(B)[:, None, None, None]
    p = np.arange(P)[None, :, None, None]
    win = conf[b, ys[:, :, :, None], xs[:, :, None, :], p]  # (B, P, k, k)
    tot = win.sum((2, 3))
    mx = (win * (xs[:, :, None, :] + 0.5)).sum((2, 3)) / np.maximum(tot, 1e-12)
    my = (win * (ys[:, :, :, None] + 0.5)).sum((2, 3)) / np.maximum(tot, 1e-12)
    refined = np.stack([mx, my], -1) * (size / Wh) - 0.5
    ok = (win.max((2, 3)) >= min_conf)[..., None]
    return np.where(ok, refined, xy_bp2)


def decode_landmarks(raw_b195: np.ndarray, heat_bhwp: np.ndarray | None, A_b23: np.ndarray,
                     size: int = LMK_SIZE) -> dict[str, np.ndarray]:
    """Landmark model outputs -> image px: xy (B, 39, 2), z (B, 39) px-scaled depth, visibility and
    presence (B, 39) in [0, 1]. ``A_b23``: each input's image -> input affine."""
    raw = raw_b195.reshape(len(raw_b195), -1, 5).astype(np.float64)
    xy_in = raw[..., :2] - 0.5  # input pixel-centre coordinates
    if heat_bhwp is not None:
        n = heat_bhwp.shape[-1]
        xy_in[:, :n] = refine_with_heatmap(xy_in[:, :n], heat_bhwp, size)
    inv = np.stack([invert_affine(A) for A in A_b23])
    xy = np.einsum("bij,bpj->bpi", inv[:, :, :2], xy_in) + inv[:, None, :, 2]
    scale = np.linalg.norm(inv[:, :, 0], axis=1)  # image px per input px
    return {"xy": xy, "z": raw[..., 2] * scale[:, None], "visibility": sigmoid(raw[..., 3]),
            "presence": sigmoid(raw[..., 4])}


def segmentation_to_image(logits_hw: np.ndarray, A_23: np.ndarray, image_wh: tuple[int, int],
                          box: tuple[int, int, int, int] | None = None) -> tuple[np.ndarray, tuple[int, int]]:
    """The ROI's segmentation probability warped back onto the image, only over the ROI's bounding
    box (clipped to the image). -> (prob (h, w) float32 over that box, its top-left (x0, y0))."""
    W, H = image_wh
    size = logits_hw.shape[0]
    inv = invert_affine(A_23)
    if box is None:
        corners = apply_affine(inv, np.array([[-0.5, -0.5], [size - 0.5, -0.5], [-0.5, size - 0.5],
                                              [size - 0.5, size - 0.5]]))
        x0, y0 = np.floor(corners.min(0)).astype(int)
        x1, y1 = np.ceil(corners.max(0)).astype(int) + 1
    else:
        x0, y0, x1, y1 = box
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if x1 <= x0 or y1 <= y0:
        return np.zeros((0, 0), np.float32), (x0, y0)
    # image (box) px -> input px, for warpAffine with WARP_INVERSE_MAP semantics
    M = A_23.copy()
    M[:, 2] += M[:, :2] @ np.array([x0, y0], np.float64)
    prob = sigmoid(logits_hw.astype(np.float32)).astype(np.float32)
    out = cv2.warpAffine(prob, M, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    return out, (x0, y0)
