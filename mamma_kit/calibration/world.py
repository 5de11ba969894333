"""The world frame: Z up and the floor at z = 0, from the board lying on the floor.

A face-up board on the floor is recognised as a still board whose printed face looks
up (within 20 degrees of the guessed up direction) and that lies lowest of all boards.
Its pose defines the world: origin at the board's origin corner, X along the board's x,
Y = -board y, Z = -board z (OpenCV board z points into the board, i.e. down). When the
board was laid on the floor at several places, the one nearest the middle of the rig
gives the origin and X, and the plane through all of them gives Z (a wide baseline pins
the floor's tilt far better than one board seen at a grazing angle). Without
such a board the world is the first camera's frame turned so that Z points up as
guessed from the rig (the plane of the camera centres) and from how people hold boards
(upright: board y points down), with a warning.
"""

from __future__ import annotations

import numpy as np

from mamma_kit.core.camera import Rig

R_WORLD_FROM_FLOOR_BOARD = np.diag([1.0, -1.0, -1.0])


def up_guess(rig: Rig, ev_R: np.ndarray, held: np.ndarray) -> tuple[np.ndarray, str]:
    """Unit up vector in the rig's current frame and how it was guessed.

    ``held`` marks events that are boards in someone's hands (not close-ups only, not the
    floor): their mean -y axis points roughly up."""
    board_up = -ev_R[held, :, 1].sum(0) if held.any() else np.zeros(3)
    cam_up = -np.stack([c.R[1] for c in rig]).sum(0)  # cameras' -y axes (upright phones)
    C = rig.centers()
    if len(C) >= 3:
        X = C - C.mean(0)
        _, sv, Vt = np.linalg.svd(X)
        # a ring of cameras: centres span a plane (third singular value small) that is not a line
        if sv[1] > 0.2 * sv[0] and sv[2] < 0.35 * sv[1]:
            n = Vt[2]
            ref = board_up if np.linalg.norm(board_up) > 0 else cam_up
            return (n if n @ ref >= 0 else -n), "plane of the camera centres"
    if np.linalg.norm(board_up) > 1e-9:
        return board_up / np.linalg.norm(board_up), "how the boards were held"
    return cam_up / np.linalg.norm(cam_up), "the cameras' up axes"


def find_floor(ev_R: np.ndarray, ev_t: np.ndarray, centres_e3: np.ndarray, still: np.ndarray, up: np.ndarray,
               cam_centres: np.ndarray, max_angle_deg: float = 20.0, same_level_m: float = 0.05
               ) -> tuple[int | None, list[int]]:
    """(origin board, all boards lying on the floor) among the events.

    Floor boards are still, face up and lowest (nothing lies clearly below them); the one
    nearest the middle of the rig (seen from above) defines the origin and the X axis."""
    face_up = -ev_R[:, :, 2] @ up > np.cos(np.radians(max_angle_deg))
    cand = np.nonzero(face_up & still)[0]
    if len(cand) == 0:
        return None, []
    h = centres_e3 @ up
    low = float(np.min(h[cand]))
    if np.min(h) < low - 0.15:  # something well below the lowest flat board: not the floor
        return None, []
    floor = [int(k) for k in cand if h[k] < low + same_level_m]
    mid = cam_centres.mean(0)
    horiz = centres_e3[floor] - mid
    horiz = horiz - np.outer(horiz @ up, up)
    origin = floor[int(np.argmin(np.linalg.norm(horiz, axis=1)))]
    return origin, floor


def world_from_floor(ev_R: np.ndarray, ev_t: np.ndarray, origin: int, floor: list[int], corners_b3: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, dict]:
    """(R_w, t_w) with X_world = R_w X_rig + t_w: Z = normal of the plane through the
    corners of every floor board, X = the origin board's x axis in that plane, origin = the
    origin board's origin corner on the plane. With one floor board this is exactly the
    board's own frame (x, -y, -z)."""
    pts = np.concatenate([corners_b3 @ ev_R[k].T + ev_t[k] for k in floor])
    mu = pts.mean(0)
    _, _, Vt = np.linalg.svd(pts - mu)
    z = Vt[2]
    if z @ (-ev_R[origin][:, 2]) < 0:
        z = -z
    if len(floor) == 1:
        z = -ev_R[origin][:, 2]
    x = ev_R[origin][:, 0] - (ev_R[origin][:, 0] @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_w = np.stack([x, y, z])
    o = ev_t[origin] - ((ev_t[origin] - mu) @ z) * z  # origin corner projected onto the plane
    dev = (pts - mu) @ z
    return R_w, -R_w @ o, {"floor_boards": len(floor), "floor_flatness_mm": float(np.abs(dev).max() * 1000)}


def world_from_board(R_e: np.ndarray, t_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R_w, t_w) with X_world = R_w X_rig + t_w for a floor board at pose (R_e, t_e)
    (board -> rig)."""
    R_w = R_WORLD_FROM_FLOOR_BOARD @ R_e.T
    return R_w, -R_w @ t_e


def world_from_camera(rig: Rig, up: np.ndarray, first: str) -> tuple[np.ndarray, np.ndarray]:
    """World = first camera's centre, Z = up, X = the camera's x axis made horizontal."""
    cam = rig[first]
    z = up / np.linalg.norm(up)
    x = cam.R[0] - (cam.R[0] @ z) * z
    if np.linalg.norm(x) < 1e-6:
        x = cam.R[2] - (cam.R[2] @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_w = np.stack([x, y, z])
    return R_w, -R_w @ cam.center
