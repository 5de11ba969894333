"""Diagnostics picture of a matching: every track against every track, ordered by person."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mamma_kit.core.identities import Identities


def affinity_table(ident: Identities) -> tuple[list[tuple[str, int]], np.ndarray]:
    """Tracks ordered by person (unassigned last) and their (N, N) affinity matrix (NaN: not compared)."""
    order = [(c, t) for p in ident.person_ids for c, t in ident.tracks_of(p)]
    order += [(u["camera"], int(u["track"])) for u in ident.unassigned]
    pos = {k: i for i, k in enumerate(order)}
    N = len(order)
    A = np.full((N, N), np.nan)
    for key, rec in ident.pairs.items():
        ca, cb = key.split("|")
        aff = np.array([[np.nan if v is None else v for v in row] for row in rec["affinity"]], float).reshape(
            len(rec["rows"]), len(rec["cols"]))
        shared = np.asarray(rec["shared_landmarks"]).reshape(aff.shape)
        for i, ta in enumerate(rec["rows"]):
            for j, tb in enumerate(rec["cols"]):
                x, y = pos.get((ca, int(ta))), pos.get((cb, int(tb)))
                if x is None or y is None or shared[i, j] == 0:
                    continue
                A[x, y] = A[y, x] = aff[i, j]
    return order, A


def plot_matching(ident: Identities, path: str | Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order, A = affinity_table(ident)
    N = len(order)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 6), gridspec_kw={"width_ratios": [3, 2]})
    cmap = plt.get_cmap("viridis").with_extremes(bad="#dddddd")
    im = ax.imshow(np.ma.masked_invalid(A), vmin=0, vmax=1, cmap=cmap, interpolation="nearest")
    fig.colorbar(im, ax=ax, fraction=0.046, label="affinity exp(-D / lambda)")
    # person blocks
    start = 0
    for p in ident.person_ids:
        n = len(ident.tracks_of(p))
        ax.add_patch(plt.Rectangle((start - 0.5, start - 0.5), n, n, fill=False, ec="red", lw=1.2))
        start += n
    if N <= 60:
        labels = [f"{c}:{t}" for c, t in order]
        ax.set_xticks(range(N), labels, rotation=90, fontsize=6)
        ax.set_yticks(range(N), labels, fontsize=6)
    ax.set_title(f"track affinities, grouped by person (red): {len(ident.person_ids)} persons, "
                 f"{len(ident.rejected)} rejected matches", fontsize=9)
    pids = ident.person_ids
    views = [len(ident.views_of(p)) for p in pids]
    bx.bar([str(p) for p in pids], views, color="#4477aa")
    bx.axhline(len(ident.cameras), color="grey", ls="--", lw=1, label=f"{len(ident.cameras)} cameras")
    bx.set_xlabel("person")
    bx.set_ylabel("views")
    bx.set_title("views per person", fontsize=9)
    bx.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    from mamma_kit.core.io import atomic_path

    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path
