"""Hand refinement: a second, closer look at each hand, at the frame's own resolution.

The body network reads a person at 160 x 120 px, where a hand is a few pixels wide; its hand
landmarks are 4-6 % of the box height off, and with ground-truth hand landmarks alone the demo's
fit error halves (issue 22). HandNet reads a square crop of the frame around one hand and
predicts that hand's 60 landmarks (xy, sigma; it learns visibility and person contact too, but on
video frames the body network's are better, so those stay the body network's). The two networks'
positions are averaged with inverse-variance weights, so a hand HandNet is unsure of keeps the body
network's landmarks; the sigma stays the body network's.

Crop contract (``hand_box``): a square of side ``frac`` x the person's size (the larger side of the
tight mask box) centred on a guess of the hand's centre, warped to HAND_IN x HAND_IN px with
crop.warp_crop (the body crops' rule, so both networks see the same resampling). Refinement is a
cascade (``CASCADE``): the body network's hand centroid, a wide crop, the refined centroid, a
tighter crop. Inputs per crop: RGB, the person's mask, the other people's mask, and the keypoint
model's wrist, pinky, index, thumb and elbow of that side drawn as Gaussians scaled by their
visibility (real-detector evidence, as the body network has), plus two coordinate channels.
Outputs are in the crop's normalised coordinates ([-1, 1] spans the crop, crop.py point 4).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn

from mamma_kit.core.errors import UserError
from mamma_kit.landmarks import crop as C

HAND_IN = 64
CASCADE = (0.42, 0.28)  # crop side / person size, wide then tight
KP_SIDE = ((15, 17, 19, 21, 13), (16, 18, 20, 22, 14))  # BlazePose wrist, pinky, index, thumb, elbow: left, right
KP_SIGMA_PX = 2.5  # Gaussian radius of a keypoint in the crop
HANDS_FORMAT = "mamma-kit/handnet-weights/1"
EMBEDDED_HANDS = Path(__file__).parent / "weights" / "hands-kp.pt"


def hand_landmark_ids(landmark_parts_l: np.ndarray, part_names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Indices (60,) each of the left and right hand's landmarks in the 512-landmark set."""
    return tuple(np.flatnonzero(np.asarray(landmark_parts_l) == part_names.index(n))
                 for n in ("left_hand", "right_hand"))


def person_size(tight_box_4: np.ndarray) -> float:
    """The person's size for hand crops: the larger side of the tight box (x1, y1, x2, y2)."""
    b = np.asarray(tight_box_4, np.float64)
    return float(max(b[2] - b[0], b[3] - b[1], 1.0))


def hand_box(centre_2: np.ndarray, size: float, frac: float) -> np.ndarray:
    """Crop box (cx, cy, side, side) of one hand crop (crop.py's box form)."""
    s = frac * size
    return np.array([centre_2[0], centre_2[1], s, s], np.float64)


def keypoint_maps(kp_px_p5: np.ndarray | None, side: int, M_23: np.ndarray) -> np.ndarray:
    """(5, HAND_IN, HAND_IN) float32 Gaussians of one side's hand keypoints (image px -> crop M),
    each scaled by the point's visibility; zeros where absent."""
    out = np.zeros((5, HAND_IN, HAND_IN), np.float32)
    if kp_px_p5 is None:
        return out
    kp = np.asarray(kp_px_p5, np.float64)[list(KP_SIDE[side])]
    ok = np.isfinite(kp[:, :2]).all(1) & (kp[:, 4] > 0)
    if not ok.any():
        return out
    uv = C.apply_affine(M_23, np.nan_to_num(kp[:, :2]))
    g = np.arange(HAND_IN, dtype=np.float32)
    for j in np.flatnonzero(ok):
        gx = np.exp(-0.5 * ((g - uv[j, 0]) / KP_SIGMA_PX) ** 2)
        gy = np.exp(-0.5 * ((g - uv[j, 1]) / KP_SIGMA_PX) ** 2)
        out[j] = float(np.clip(kp[j, 3], 0.05, 1.0)) * gy[:, None] * gx[None, :]
    return out


def hand_inputs(image_hw3: np.ndarray, mask_hw: np.ndarray | None, others_hw: np.ndarray | None,
                kp_px_p5: np.ndarray | None, side: int, box_4: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One hand crop's network input (10, HAND_IN, HAND_IN) uint8-range float32 channels RGB, mask,
    others, 5 keypoint maps (x 255), and M (2, 3) image px -> crop px. Training and inference both
    cut crops here."""
    wh = (HAND_IN, HAND_IN)
    img, m, M = C.warp_crop(image_hw3, box_4, wh, None if mask_hw is None else mask_hw.astype(np.uint8))
    chans = [img.transpose(2, 0, 1).astype(np.float32)]
    chans.append(np.zeros((1,) + wh, np.float32) if m is None else (m[None] > 0).astype(np.float32) * 255.0)
    if others_hw is None or not others_hw.any():
        chans.append(np.zeros((1,) + wh, np.float32))
    else:  # nearest, like the mask; warpAffine only computes the crop's pixels
        o = cv2.warpAffine(others_hw.astype(np.uint8), M, wh, flags=cv2.INTER_NEAREST,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        chans.append((o[None] > 0).astype(np.float32) * 255.0)
    chans.append(keypoint_maps(kp_px_p5, side, M) * 255.0)
    return np.concatenate(chans, 0), M


@dataclass(frozen=True)
class HandNetConfig:
    n_landmarks: int = 60  # per hand
    width: int = 32
    hidden: int = 384


def _block(cin: int, cout: int, stride: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class HandNet(nn.Module):
    """(B, 10, 64, 64) crops + side (B,) 0 left / 1 right -> xy (B, L, 2) normalised to the crop,
    log_sigma (B, L) in the same units, vis_logit and contact_logit (B, L) (touching another person).
    A plain strided CNN with coordinate channels and one regression head per side."""

    def __init__(self, cfg: HandNetConfig = HandNetConfig()):
        super().__init__()
        self.cfg = cfg
        w = cfg.width
        self.features = nn.Sequential(_block(12, w, 2), _block(w, w, 1), _block(w, 2 * w, 2), _block(2 * w, 2 * w, 1),
                                      _block(2 * w, 4 * w, 2), _block(4 * w, 4 * w, 1), _block(4 * w, 8 * w, 2),
                                      nn.Conv2d(8 * w, 4 * w, 1))
        n_feat = 4 * w * (HAND_IN // 16) ** 2
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(n_feat, cfg.hidden), nn.ReLU(inplace=True),
                                  nn.Linear(cfg.hidden, 2 * cfg.n_landmarks * 5))
        mean = torch.tensor([123.7, 116.3, 103.5, 127.5, 127.5] + [40.0] * 5)
        std = torch.tensor([58.4, 57.1, 57.4, 127.5, 127.5] + [60.0] * 5)
        self.register_buffer("mean", mean[None, :, None, None], persistent=False)
        self.register_buffer("std", std[None, :, None, None], persistent=False)
        g = torch.linspace(-1, 1, HAND_IN)
        self.register_buffer("coords", torch.stack(torch.meshgrid(g, g, indexing="xy"))[None], persistent=False)

    def forward(self, x_bchw: torch.Tensor, side_b: torch.Tensor) -> dict[str, torch.Tensor]:
        x = (x_bchw - self.mean) / self.std
        x = torch.cat([x, self.coords.expand(len(x), -1, -1, -1)], 1)
        L = self.cfg.n_landmarks
        out = self.head(self.features(x)).view(len(x), 2, L, 5)
        out = out[torch.arange(len(x)), side_b.long()]  # (B, L, 5)
        return {"xy": out[..., :2], "log_sigma": out[..., 2].clamp(-7, 2), "vis_logit": out[..., 3],
                "contact_logit": out[..., 4]}


# ---- weights -----------------------------------------------------------------------------------------
def save_hand_weights(path: Path, model: HandNet, landmark_set: str, card: dict) -> Path:
    sd = {k: v.detach().to(torch.float16) if v.is_floating_point() else v for k, v in model.state_dict().items()}
    torch.save({"format": HANDS_FORMAT, "config": asdict(model.cfg), "state_dict": sd, "landmark_set": landmark_set,
                "card": card}, path)
    return path


@dataclass
class LoadedHands:
    model: HandNet
    landmark_set: str
    source: str
    card: dict


def load_hand_weights(path: Path | str | None = None) -> LoadedHands:
    path = Path(path) if path else EMBEDDED_HANDS
    if not path.is_file():
        raise UserError(f"hand network weights not found: {path}",
                        "reinstall mamma-kit" if path == EMBEDDED_HANDS else
                        "--hands takes auto, off or the path of a hand weights .pt file")
    d = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(d, dict) or d.get("format") != HANDS_FORMAT:
        raise UserError(f"{path} is not a mamma-kit hand network file", "pass the hands-kp.pt that mamma-kit ships")
    model = HandNet(HandNetConfig(**d["config"]))
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in d["state_dict"].items()})
    return LoadedHands(model.eval(), d["landmark_set"], str(path), d.get("card", {}))


# ---- inference -----------------------------------------------------------------------------------------
class HandRefiner:
    """Refines the hand landmarks of body-network predictions with HandNet (module docstring)."""

    def __init__(self, loaded: LoadedHands, landmark_parts_l: np.ndarray, part_names: list[str],
                 cascade: tuple[float, ...] = CASCADE, sigma_scale: float | None = None, fuse: bool = True):
        self.loaded = loaded
        self.model = loaded.model.eval()
        self.ids = hand_landmark_ids(landmark_parts_l, part_names)
        self.cascade = cascade
        # measured on a held-out video capture (benchmarks/hand_sigma.py) and kept in the card: the
        # network's sigma is learnt on crops and comes out too small on video frames
        self.sigma_scale = float(loaded.card.get("sigma_scale", 1.0) if sigma_scale is None else sigma_scale)
        self.fuse = fuse  # False: HandNet's own landmarks replace the body network's (calibration)

    @torch.inference_mode()
    def predict(self, x_b10hw: np.ndarray, side_b: np.ndarray) -> dict[str, np.ndarray]:
        out = self.model(torch.as_tensor(x_b10hw), torch.as_tensor(side_b))
        return {"xy_n": out["xy"].numpy().astype(np.float64), "log_sigma": out["log_sigma"].numpy().astype(np.float64),
                "visibility": torch.sigmoid(out["vis_logit"]).numpy(),
                "contact": torch.sigmoid(out["contact_logit"]).numpy()}

    def refine(self, people: list[dict], side: int | None = None) -> None:
        """Refine in place each person's hand landmarks (or only ``side``'s: 0 left, 1 right), all in one
        batch per cascade step. A person is a dict with ``image`` (H, W, 3) its frame, ``xy`` and
        ``sigma`` (L, 2) image px and, optionally, ``visibility`` (L,) from the body network,
        ``tight_box`` (4,) its mask's, ``mask`` / ``others`` (H, W) bool or None, ``keypoints``
        (33, 5) image px or None."""
        sides = (0, 1) if side is None else (side,)
        jobs = [(p, s) for p in people for s in sides if np.isfinite(p["xy"][self.ids[s]]).all()]
        if not jobs:
            return
        centres = [p["xy"][self.ids[s]].mean(0) for p, s in jobs]
        for k, frac in enumerate(self.cascade):
            xs, Ms, boxes = [], [], []
            for (p, s), c in zip(jobs, centres):
                box = hand_box(c, person_size(p["tight_box"]), frac)
                x, M = hand_inputs(p["image"], p["mask"], p["others"], p["keypoints"], s, box)
                xs.append(x), Ms.append(M), boxes.append(box)
            net = self.predict(np.stack(xs), np.array([s for _, s in jobs]))
            for i, ((p, s), M, box) in enumerate(zip(jobs, Ms, boxes)):
                uv = C.normalised_to_crop(net["xy_n"][i], (HAND_IN, HAND_IN))
                xy = C.apply_affine(C.invert_affine(M), uv)
                if k < len(self.cascade) - 1:
                    centres[i] = xy.mean(0)
                    continue
                ids = self.ids[s]
                sig = self.sigma_scale * np.exp(net["log_sigma"][i])[:, None] * box[2] / 2.0  # (60, 1) px
                # the two networks' estimates weighted by their inverse variances (where HandNet is
                # unsure, the body's stays); the sigma stays the body network's: both read the same
                # masks and keypoints, so their errors are not independent and the product's sigma
                # would claim too much (measured: the fit is no better with it, and worse on the demo)
                w_b, w_h = (1.0 / p["sigma"][ids] ** 2 if self.fuse else 0.0), 1.0 / sig ** 2
                if self.fuse and "visibility" in p:  # a hidden landmark shows HandNet nothing to go by
                    w_h = w_h * np.clip(p["visibility"][ids], 0.05, 1.0)[:, None]
                p["xy"][ids] = (w_b * p["xy"][ids] + w_h * xy) / (w_b + w_h)
                if not self.fuse:
                    p["sigma"][ids] = sig


def hand_refiner(landmark_set: str, hands: "str | Path | HandRefiner | None" = "auto") -> HandRefiner | None:
    """The refiner for a body network's ``landmark_set``: ``hands`` "auto" (the shipped weights when
    they were trained for this landmark set, else none), "off", a weights path (must match), or a
    HandRefiner (used as it is)."""
    if isinstance(hands, HandRefiner):
        return hands
    if hands in (None, "off", "none", False):
        return None
    auto = str(hands) == "auto"
    path = EMBEDDED_HANDS if auto else Path(hands)
    if auto and not path.is_file():
        return None
    loaded = load_hand_weights(path)
    if loaded.landmark_set != landmark_set:
        if auto:
            return None
        raise UserError(f"hand network {path} predicts landmark set '{loaded.landmark_set}', the body network "
                        f"'{landmark_set}'", "pass --hands off, or hand weights trained on the same landmark set")
    return HandRefiner(loaded, *landmark_parts())


def landmark_parts() -> tuple[np.ndarray, list[str]]:
    """(part of each of the 512 landmarks (L,), part names) of the open body's landmark set, the one
    the embedded networks predict."""
    from mamma_kit.body.model import load_body_model
    from mamma_kit.body.skeleton import LANDMARK_PART_NAMES

    return load_body_model("open").landmark_parts, list(LANDMARK_PART_NAMES)
