"""The report's matplotlib figures (Agg backend), each written as a PNG under report/.

- ``rig_figure``: cameras (frusta) and the fitted people in the world, 3D and from above;
- ``reprojection_figure``: per camera, the median reprojection error per frame and person;
- ``contact_time_figure``: per person, mean person-contact and floor-contact probability;
- ``contact_landmarks_figure``: the rest-pose landmarks coloured by mean contact probability;
- ``gt_fit_figure``: MPJPE / PA-MPJPE per person against ground truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mamma_kit.core.io import atomic_path
from mamma_kit.core.colour import person_colour

DPI = 100
GT_LABELS = {"mpjpe_mm": "MPJPE", "pa_mpjpe_mm": "PA-MPJPE", "mpjpe_body_mm": "MPJPE body",
             "mpjpe_hands_mm": "MPJPE hands", "pve_mm": "PVE"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: Path) -> Path:
    """Write the figure as PNG atomically and free it."""
    plt = _plt()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI, format="png", bbox_inches="tight")
    plt.close(fig)
    return path


# ---- the rig ------------------------------------------------------------------------------
def _frustum_lines(cam, depth: float) -> np.ndarray:
    """(8, 2, 3) segments: centre to the four image corners at ``depth`` and the far rectangle."""
    w, h = cam.size
    corners_42 = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], float)
    far_43 = cam.unproject(corners_42, np.full(4, depth))
    rays = np.stack([np.broadcast_to(cam.center, (4, 3)), far_43], 1)
    rect = np.stack([far_43, np.roll(far_43, -1, axis=0)], 1)
    return np.concatenate([rays, rect])


def rig_figure(rig, people: list[tuple[int, np.ndarray]], parents: np.ndarray, path: Path) -> Path:
    """``people``: (person id, joints (T, 55, 3)) of every fitted person."""
    plt = _plt()
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    centres_c3 = rig.centers()
    pelvis = [(pid, J[:, 0]) for pid, J in people]
    pts = np.concatenate([centres_c3, np.zeros((1, 3))] + [p for _, p in pelvis])
    lo, hi = pts.min(0), pts.max(0)
    span = float(max(np.ptp(pts[:, :2], axis=0).max(), 1.0))
    depth = 0.12 * span
    fig = plt.figure(figsize=(12.5, 5.6))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    top = fig.add_subplot(1, 2, 2)

    # floor grid at z = 0, 1 m spacing around everything
    g0, g1 = np.floor(lo[:2] - 0.5), np.ceil(hi[:2] + 0.5)
    xs, ys = np.arange(g0[0], g1[0] + 1), np.arange(g0[1], g1[1] + 1)
    grid = [np.array([[x, g0[1], 0], [x, g1[1], 0]]) for x in xs] + [np.array([[g0[0], y, 0], [g1[0], y, 0]])
                                                                     for y in ys]
    ax.add_collection3d(Line3DCollection(grid, colors="#cccccc", linewidths=0.5))
    for x in xs:
        top.axvline(x, color="#eeeeee", lw=0.6, zorder=0)
    for y in ys:
        top.axhline(y, color="#eeeeee", lw=0.6, zorder=0)

    segs = np.concatenate([_frustum_lines(c, depth) for c in rig])
    ax.add_collection3d(Line3DCollection(segs, colors="#1f5f99", linewidths=0.9))
    top.plot(*segs[..., :2].transpose(2, 1, 0), color="#1f5f99", lw=0.7)
    ax.scatter(*centres_c3.T, color="#1f5f99", s=14)
    top.scatter(*centres_c3[:, :2].T, color="#1f5f99", s=14, zorder=3)
    for c in rig:
        ax.text(*c.center, f" {c.name}", fontsize=8)
        top.annotate(c.name, c.center[:2], xytext=(5, 5), textcoords="offset points", fontsize=8)
    for i, col in enumerate(("r", "g", "b")):  # world axes, 0.5 m
        ax.plot(*np.c_[np.zeros(3), np.eye(3)[i] * 0.5], color=col, lw=2)

    body = np.arange(1, 22)  # the 21 body bones (no hands or face) for the stick figure
    for pid, J_tj3 in people:
        col = person_colour(pid)
        mid = J_tj3[len(J_tj3) // 2]
        bones = np.stack([mid[body], mid[parents[body]]], 1)
        ax.add_collection3d(Line3DCollection(bones, colors=[col], linewidths=1.6))
        m = J_tj3[:, 0].mean(0)
        ax.scatter(*m, color=col, s=40, marker="o", edgecolor="k", label=f"person {pid} (mean pelvis)")
        top.plot(*J_tj3[:, 0, :2].T, color=col, lw=1.2, alpha=0.8)
        top.scatter(*m[:2], color=col, s=60, edgecolor="k", zorder=4, label=f"person {pid}")
        top.annotate(f"P{pid}", m[:2], xytext=(6, -10), textcoords="offset points", fontsize=9, color="k")

    mid3 = (lo + hi) / 2
    r = float(np.ptp(pts[:, :2], axis=0).max()) / 2 * 1.05 + 0.3
    # metres equal on all axes, but not flatter than about 1:2 (people are ~2 m tall)
    z_top = max(float(hi[2]) + 0.3, 2.3, 0.45 * 2 * r)
    ax.set_xlim(mid3[0] - r, mid3[0] + r)
    ax.set_ylim(mid3[1] - r, mid3[1] + r)
    ax.set_zlim(0, z_top)
    ax.set_box_aspect((2 * r, 2 * r, z_top))
    ax.set_zticks(np.arange(0, z_top + 1e-9, 1.0))
    ax.view_init(elev=28, azim=-60)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(f"rig{' and people' if people else ''} (world, Z up, floor z = 0)", fontsize=10)
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title(f"from above: cameras{' and pelvis paths' if people else ''}", fontsize=10)
    if people:
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return save(fig, path)


# ---- fit quality over time ------------------------------------------------------------------
def reprojection_figure(series, cameras: list[str], path: Path) -> Path:
    """``series``: analysis.Series (camera, person, t_ref, median px) curves."""
    plt = _plt()
    cams = [c for c in cameras if any(s.camera == c for s in series)]
    fig, axes = plt.subplots(len(cams), 1, figsize=(11, 1.2 + 1.7 * len(cams)), sharex=True, squeeze=False)
    for ax, cam in zip(axes[:, 0], cams):
        vals = []
        for s in (s for s in series if s.camera == cam):
            ax.plot(s.t_ref, s.value, ".-", ms=3, lw=1, color=person_colour(s.person), label=f"person {s.person}")
            vals.append(s.value[np.isfinite(s.value)])
        v = np.concatenate(vals)
        ax.axhline(np.median(v), color="grey", lw=0.8, ls="--")
        ax.set_ylabel(f"{cam}\npx")
        ax.set_ylim(0, max(1.0, float(np.percentile(v, 99)) * 1.15))
        ax.text(0.995, 0.92, f"median {np.median(v):.2f} px", transform=ax.transAxes, ha="right", va="top",
                fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="upper left", ncol=6)
    axes[-1, 0].set_xlabel("reference time (s)")
    fig.suptitle("median reprojection error of visible landmarks per frame", fontsize=10)
    fig.tight_layout()
    return save(fig, path)


def contact_time_figure(grid: np.ndarray, contact: dict, cameras: list[str], path: Path) -> Path:
    """``contact``: {person: {"contact": (C, N), "floor": (C, N)}} on ``grid`` (N,) (analysis)."""
    plt = _plt()
    import warnings

    pids = sorted(contact)
    fig, axes = plt.subplots(len(pids), 2, figsize=(11, 1.2 + 1.9 * len(pids)), sharex=True, squeeze=False)
    for row, pid in zip(axes, pids):
        col = person_colour(pid)
        for ax, key, title in ((row[0], "contact", "person contact"), (row[1], "floor", "floor contact")):
            v_cn = contact[pid][key]
            with warnings.catch_warnings():  # frames no view sees stay NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                mean, lo, hi = np.nanmean(v_cn, 0), np.nanmin(v_cn, 0), np.nanmax(v_cn, 0)
            ax.fill_between(grid, lo, hi, color=col, alpha=0.2, lw=0, label="range over views")
            ax.plot(grid, mean, color=col, lw=1.4, label="mean over views")
            ax.set_title(f"person {pid}: {title}", fontsize=9)
            ax.set_ylim(0, max(0.05, float(np.nanmax(hi, initial=0)) * 1.15))
            ax.grid(alpha=0.3)
        row[0].set_ylabel("mean prob.")
    axes[0, 0].legend(fontsize=7, loc="upper left")
    for ax in axes[-1]:
        ax.set_xlabel("reference time (s)")
    fig.suptitle(f"mean contact probability over the 512 landmarks ({len(cameras)} views)", fontsize=10)
    fig.tight_layout()
    return save(fig, path)


def contact_landmarks_figure(rest_l3: np.ndarray, contact_l: np.ndarray, floor_l: np.ndarray, path: Path) -> Path:
    """Rest-pose landmarks (canonical Y up, facing +Z) from the front and the side, coloured by
    their mean person-contact and floor-contact probability."""
    plt = _plt()
    from matplotlib.colors import LinearSegmentedColormap

    cmap = LinearSegmentedColormap.from_list("contact", ["#c3c8cf", "#f4a259", "#c1121f", "#4a0a0f"])
    fig, axes = plt.subplots(1, 4, figsize=(12, 4.6), layout="constrained",
                             gridspec_kw={"width_ratios": [1.3, 0.75, 1.3, 0.75]})
    for k, (vals, title) in enumerate(((contact_l, "person contact"), (floor_l, "floor contact"))):
        order = np.argsort(vals)  # most likely contacts drawn last (on top)
        vmax = max(0.05, float(vals.max(initial=0)))
        for j, (a, b, view) in enumerate(((0, 1, "front"), (2, 1, "side"))):
            ax = axes[2 * k + j]
            sc = ax.scatter(rest_l3[order, a], rest_l3[order, b], c=vals[order], s=10, cmap=cmap, vmin=0,
                            vmax=vmax, edgecolors="none")
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{title} ({view})", fontsize=9)
        fig.colorbar(sc, ax=axes[2 * k:2 * k + 2], fraction=0.04, label="mean probability")
    return save(fig, path)


# ---- ground truth ---------------------------------------------------------------------------
def gt_fit_figure(people: list[dict], path: Path) -> Path:
    """``people``: evaluation 'fit' group's per-person dicts (mpjpe_mm, pa_mpjpe_mm, ...)."""
    plt = _plt()
    keys = [k for k in GT_LABELS if any(k in p for p in people)]
    n = len(people)
    fig, ax = plt.subplots(figsize=(max(5.5, 1.6 + 1.3 * n * len(keys) / 3), 3.4))
    width = 0.8 / len(keys)
    x = np.arange(n)
    cmap = plt.get_cmap("tab10")
    for i, k in enumerate(keys):
        vals = np.array([p.get(k, np.nan) for p in people], float)
        bars = ax.bar(x + (i - (len(keys) - 1) / 2) * width, vals, width, color=cmap(i), label=GT_LABELS[k])
        ax.bar_label(bars, fmt="%.0f", fontsize=7)
    ax.set_xticks(x, [f"person {p.get('person')}" for p in people])
    ax.set_ylabel("mm")
    ax.set_title("joint errors against ground truth", fontsize=10)
    ax.legend(fontsize=7, ncol=len(keys), loc="upper center", bbox_to_anchor=(0.5, -0.12))
    ax.grid(axis="y", alpha=0.3)
    return save(fig, path)
