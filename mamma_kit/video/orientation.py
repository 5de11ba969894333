"""How a stored frame is turned to be shown upright: the file's display matrix, as players apply it.

Phones store a portrait video as landscape frames plus a display matrix (a rotation, sometimes
with a mirror) that every player, ffmpeg (``-autorotate``) and OpenCV (CAP_PROP_ORIENTATION_AUTO)
apply. mamma-kit works in the displayed frame: calibrations, masks, keypoints and the fit all see
the people upright, as the user does.

The 3x3 display matrix is nine int32 (16.16 fixed point for the 2x2 part); ffmpeg's rule is
followed exactly: ``theta`` = clockwise degrees = -av_display_rotation_get, and the signs of
entries 0, 3 and 4 choose between a rotation and a transpose (a mirror). ``cw`` below is that
clockwise rotation, as a user reads it ("rotation 90" = the phone was held upright).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

ROTATIONS = (0, 90, 180, 270)


@dataclass(frozen=True)
class Orientation:
    """``cw`` clockwise degrees (0, 90, 180, 270) and ``mirror`` (a left-right flip after the turn)."""

    cw: int = 0
    mirror: bool = False

    @property
    def is_identity(self) -> bool:
        return self.cw == 0 and not self.mirror

    def displayed_size(self, width: int, height: int) -> tuple[int, int]:
        """(width, height) of the displayed frame for a stored ``width`` x ``height``."""
        return (height, width) if self.cw in (90, 270) else (width, height)

    def apply(self, img_hw: np.ndarray) -> np.ndarray:
        """The displayed frame (contiguous) of a stored frame (H, W) or (H, W, C)."""
        if self.is_identity:
            return img_hw
        out = np.rot90(img_hw, k=-(self.cw // 90))  # np.rot90 turns counter-clockwise for k > 0
        if self.mirror:
            out = out[:, ::-1]
        return np.ascontiguousarray(out)

    def stored_size(self, width: int, height: int) -> tuple[int, int]:
        """(width, height) stored for a displayed ``width`` x ``height`` (a quarter turn swaps them)."""
        return self.displayed_size(width, height)

    def unapply(self, img_hw: np.ndarray) -> np.ndarray:
        """The stored frame of a displayed one (the inverse of :meth:`apply`)."""
        if self.is_identity:
            return img_hw
        out = img_hw[:, ::-1] if self.mirror else img_hw
        return np.ascontiguousarray(np.rot90(out, k=self.cw // 90))

    def label(self) -> str:
        return f"{self.cw}" + (" mirrored" if self.mirror else "")


def from_display_matrix(m9: np.ndarray | None) -> Orientation:
    """The Orientation players give a file whose display matrix is ``m9`` (9 int32; None: none)."""
    if m9 is None:
        return Orientation()
    m = np.asarray(m9, np.int64).ravel()
    a, b, c, d = (float(m[i]) / 65536.0 for i in (0, 1, 3, 4))
    sx, sy = math.hypot(a, c), math.hypot(b, d)
    if sx == 0 or sy == 0:
        return Orientation()
    # ffmpeg's get_rotation: theta = -av_display_rotation_get(m) = atan2(b, a), clockwise degrees
    theta = round(math.degrees(math.atan2(b / sy, a / sx))) % 360
    theta = int(90 * round(theta / 90)) % 360  # odd angles (never written by phones) snap to a quarter turn
    # ffmpeg's filters for each case, each written as a clockwise turn then an optional mirror
    if theta == 90:  # transpose=cclock_flip (a plain transpose) if m[3] > 0, else clock
        return Orientation(270, True) if m[3] > 0 else Orientation(90, False)
    if theta == 180:  # hflip if m[0] < 0, vflip if m[4] < 0
        h, v = m[0] < 0, m[4] < 0
        return Orientation(180, False) if h and v else Orientation(0, True) if h else \
            Orientation(180, True) if v else Orientation(0, False)
    if theta == 270:  # transpose=clock_flip (an anti-transpose) if m[3] < 0, else cclock
        return Orientation(90, True) if m[3] < 0 else Orientation(270, False)
    return Orientation(180, True) if m[4] < 0 else Orientation()  # vflip = a half turn, mirrored


def display_matrix(o: Orientation) -> np.ndarray:
    """The 9 int32 display matrix that players (ffmpeg's rule, from_display_matrix) turn into ``o``;
    for writing phone-like files."""
    for cw in ROTATIONS:
        rad = math.radians(cw)
        c, s = round(math.cos(rad)), round(math.sin(rad))
        for flip in (1, -1):  # av_display_matrix_flip (hflip) negates the first column
            m = np.array([flip * c, s, 0, -flip * s, c, 0, 0, 0, 0], np.int64) * 65536
            m[8] = 1 << 30
            if from_display_matrix(m) == o:
                return m.astype(np.int32)
    raise ValueError(f"no display matrix gives {o}")
