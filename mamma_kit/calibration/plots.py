"""Calibration figures (matplotlib, Agg): what a user needs to judge and improve a calibration.

- ``camera_<name>.png``: residual vectors over the image, per-view errors, coverage heat
  map, cross-validation (projection difference between two halves of the views);
- ``connectivity.png``: which cameras share still-board views, and how many;
- ``rig.png``: the calibrated rig in 3D (cameras, boards, floor board, world axes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mamma_kit.core.io import atomic_path


def _fig(w_in: float, h_in: float):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    return Figure(figsize=(w_in, h_in), dpi=110, layout="constrained")


def _save(fig, path: Path) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return str(path)


def camera_figure(result, name: str, path: Path) -> str:
    """Four panels for one camera (see the module docstring)."""
    names = result.bundle.names
    k = names.index(name)
    ba = result.bundle
    cam = result.rig[name]
    diag = result.camera_diagnostics[name]
    w, h = cam.size
    m = ba.obs_cam == k
    inl = m & ba.inlier
    out = m & ~ba.inlier
    xy = ba.obs_xy
    res = ba.residual
    fig = _fig(12, 8.6)
    axs = fig.subplots(2, 2)
    # residual vectors, exaggerated so that 1 px of error spans 2 % of the image width
    ax = axs[0, 0]
    scale = 0.02 * w
    mag = np.linalg.norm(res[inl], axis=1)
    q = ax.quiver(xy[inl, 0], xy[inl, 1], res[inl, 0] * scale, res[inl, 1] * scale, mag, angles="xy",
                  scale_units="xy", scale=1, cmap="viridis", width=0.0025)
    if out.any():
        ax.plot(xy[out, 0], xy[out, 1], "rx", ms=4, label=f"{int(out.sum())} outliers (dropped)")
        ax.legend(loc="upper right", fontsize=7)
    fig.colorbar(q, ax=ax, label="reprojection error (px)", shrink=0.8)
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_title(f"residuals (arrows x{scale:.0f}): rms {diag['rms_px']:.3f} px", fontsize=9)
    # per-view errors
    ax = axs[0, 1]
    ev_ids = np.unique(ba.obs_evt[inl])
    kinds = [("shared" if len(result.events[e].obs) > 1 else result.events[e].kind) for e in ev_ids]
    colors = {"shared": "tab:green", "hold": "tab:blue", "view": "tab:orange", "sync": "tab:purple"}
    vals = diag["per_view_rms_px"]
    ax.bar(np.arange(len(vals)), vals, color=[colors.get(kd, "grey") for kd in kinds], width=0.85)
    from matplotlib.patches import Patch

    labels = {"shared": "board seen with other cameras", "hold": "still board, this camera only",
              "view": "intrinsics view", "sync": "simultaneous frames"}
    ax.axhline(diag["rms_px"], color="k", lw=0.8, ls="--")
    ax.set_xlabel("view (board pose)")
    ax.set_ylabel("rms (px)")
    ax.legend(handles=[Patch(color=colors[k], label=labels[k]) for k in colors if k in kinds], fontsize=7)
    ax.set_title(f"per-view error: worst {diag['per_view_max_px']:.3f} px over {len(vals)} views", fontsize=9)
    # coverage
    ax = axs[1, 0]
    nx = 32
    ny = max(2, round(nx * h / w))
    H, xe, ye = np.histogram2d(xy[inl, 0], xy[inl, 1], bins=[nx, ny], range=[[0, w], [0, h]])
    im = ax.imshow(H.T, extent=(0, w, h, 0), cmap="magma", interpolation="nearest")
    fig.colorbar(im, ax=ax, label="corners per cell", shrink=0.8)
    ax.set_title(f"coverage: {100 * diag['coverage']:.0f} % of the image (intrinsic views); "
                 f"max tilt {diag['max_tilt_deg']:.0f} deg", fontsize=9)
    # cross-validation
    ax = axs[1, 1]
    cv = result.cross_validation.get(name)
    if cv is not None:
        g = cv["xy"]
        gx = np.unique(g[:, 0])
        gy = np.unique(g[:, 1])
        D = cv["diff_px"].reshape(len(gy), len(gx))
        im = ax.imshow(D, extent=(gx[0], gx[-1], gy[-1], gy[0]), cmap="inferno", interpolation="bilinear")
        fig.colorbar(im, ax=ax, label="px", shrink=0.8)
        ax.set_title(f"cross-validation (two halves of the views): median {cv['median_px']:.2f}, "
                     f"max {cv['max_px']:.2f} px", fontsize=9)
    else:
        ax.text(0.5, 0.5, "no cross-validation\n(fixed intrinsics or fewer than 8 views)", ha="center",
                va="center", transform=ax.transAxes)
        ax.set_axis_off()
    for a in (axs[1, 0], axs[1, 1]):
        a.set_xlim(0, w)
        a.set_ylim(h, 0)
    std = diag.get("bundle_std") or {}
    fx_s = f" +- {std['fx']:.2f}" if "fx" in std else ""
    fig.suptitle(f"camera {name}: {w}x{h}, fx {cam.K[0, 0]:.1f}{fx_s} px, {cam.model} "
                 f"{np.array2string(cam.dist, precision=4, separator=', ')}", fontsize=10)
    return _save(fig, path)


def connectivity_figure(result, path: Path) -> str:
    rig = result.rig
    C = rig.centers()
    fig = _fig(6.5, 6)
    ax = fig.subplots()
    counts = result.pairs
    mx = max(counts.values()) if counts else 1
    for (a, b), n in counts.items():
        if n <= 0:
            continue
        pa, pb = rig[a].center, rig[b].center
        ax.plot([pa[0], pb[0]], [pa[1], pb[1]], "-", color="tab:green", lw=1 + 5 * n / mx, alpha=0.7, zorder=1)
        mid = 0.62 * pa + 0.38 * pb  # off-centre so crossing edges keep their labels apart
        ax.text(mid[0], mid[1], str(n), fontsize=9, ha="center", va="center",
                bbox=dict(boxstyle="round", fc="white", ec="tab:green", lw=0.5), zorder=3)
    ax.scatter(C[:, 0], C[:, 1], s=220, c="tab:blue", zorder=2)
    for c in rig:
        ax.annotate(c.name, c.center[:2], xytext=(8, 8), textcoords="offset points", fontsize=10)
    ax.set_aspect("equal")
    ax.margins(0.15)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("still-board views shared by camera pairs (seen from above)", fontsize=10)
    return _save(fig, path)


def rig_figure(result, spec, path: Path) -> str:
    rig = result.rig
    fig = _fig(8, 7)
    ax = fig.add_subplot(projection="3d")
    R_w, t_w = result.world_R, result.world_t
    ba = result.bundle
    # board poses in the world
    eR = np.einsum("ij,ejk->eik", R_w, ba.event_R)
    et = ba.event_t @ R_w.T + t_w
    cen = np.einsum("eij,j->ei", eR, spec.center_b3) + et
    shared = np.array([len(ev.obs) > 1 for ev in result.events])
    ax.scatter(*cen[~shared].T, s=4, c="tab:orange", alpha=0.5, label="single-camera boards")
    ax.scatter(*cen[shared].T, s=12, c="tab:green", label="shared boards")
    W, H = spec.size_m
    outline = np.array([[0, 0, 0], [W, 0, 0], [W, H, 0], [0, H, 0], [0, 0, 0]])
    if result.diagnostics["world"].get("source") == "floor":
        ax.plot(*(outline @ np.diag([1, -1, -1])).T, "k-", lw=1.5, label="floor board")
    span = max(np.ptp(rig.centers(), axis=0).max(), 1.0)
    L = 0.12 * span
    for c in rig:
        C = c.center
        w, h = c.size
        corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
        rays = c.unproject(corners)
        rays = rays / np.linalg.norm(rays, axis=1, keepdims=True) * L
        pts = rays @ c.R + C
        for p in pts:
            ax.plot(*np.c_[C, p], color="tab:blue", lw=0.8)
        ax.plot(*np.r_[pts, pts[:1]].T, color="tab:blue", lw=0.8)
        ax.text(*C, f" {c.name}", fontsize=9)
    for i, col in enumerate(("r", "g", "b")):
        ax.plot(*np.c_[np.zeros(3), np.eye(3)[i] * 0.5], color=col, lw=2)
    allp = np.r_[rig.centers(), cen, np.zeros((1, 3))]
    mid = (allp.max(0) + allp.min(0)) / 2
    r = np.ptp(allp, axis=0).max() / 2 * 1.1
    ax.set_xlim(mid[0] - r, mid[0] + r)
    ax.set_ylim(mid[1] - r, mid[1] + r)
    ax.set_zlim(max(mid[2] - r, -0.2), mid[2] + r)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    src = result.diagnostics["world"].get("source")
    ax.set_title("calibrated rig (world Z up, floor z = 0)" if src == "floor" else
                 "calibrated rig (world = first camera, Z up guessed)", fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    return _save(fig, path)


def write_figures(result, spec, folder: Path) -> list[str]:
    folder = Path(folder)
    out = [camera_figure(result, n, folder / f"camera_{n}.png") for n in result.rig.names]
    if len(result.rig) > 1:
        out.append(connectivity_figure(result, folder / "connectivity.png"))
    out.append(rig_figure(result, spec, folder / "rig.png"))
    return out
