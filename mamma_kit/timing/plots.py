"""Pictures of a sync result (matplotlib, Agg): offsets and drift, residuals over time,
correlation peaks, agreement between methods."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mamma_kit.core.io import atomic_path


def _save(fig, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    return path


def plot_sync(result, out_dir: str | Path) -> list[Path]:
    """Write PNGs for a :class:`~mamma_kit.timing.sync.SyncResult`; return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    names = list(result.clocks)
    # 1. offsets and drift with confidence
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
    off = [result.clocks[n].offset * 1e3 for n in names]
    ppm = [result.clocks[n].rate_ppm for n in names]
    ax[0].bar(names, off, color="tab:blue")
    ax[0].set_ylabel("offset (ms)")
    ax[0].set_title(f"offset to {result.reference} ({result.method})")
    for i, n in enumerate(names):
        ax[0].annotate(f"conf {result.clocks[n].confidence:.2f}", (i, off[i]), ha="center", va="bottom", fontsize=7)
    ax[1].bar(names, ppm, color="tab:orange")
    ax[1].set_ylabel("drift (ppm)")
    ax[1].set_title("clock drift")
    fig.tight_layout()
    paths.append(_save(fig, out / "offsets.png"))
    plt.close(fig)
    # 2. residuals over time
    fig, ax = plt.subplots(figsize=(9, 3.4))
    drew = False
    if result.ltc:
        for n, lc in result.ltc.items():
            r = lc.fit.residual_n * 1e6
            ax.plot(lc.t_cam_f[: len(r)], r, ".", ms=2, label=f"{n} LTC")
            drew = True
        ax.set_ylabel("residual (µs)")
    elif result.clap:
        for n in names:
            if n == result.reference:
                continue
            obs = [o for o in result.clap.observations if result.reference in (o.i, o.j) and n in (o.i, o.j)]
            t = [o.t_i if o.i == result.reference else o.t_j for o in obs]
            ax.plot(t, [o.residual_s * 1e3 for o in obs], "o-", label=f"{n} clap")
            drew = True
        ax.set_ylabel("residual (ms)")
    ax.set_xlabel(f"time (s, {result.reference})" if not result.ltc else "camera time (s)")
    ax.set_title("residuals of the clock fit over the take")
    ax.axhline(0, color="k", lw=0.5)
    if drew:
        ax.legend(fontsize=7)
    fig.tight_layout()
    paths.append(_save(fig, out / "residuals.png"))
    plt.close(fig)
    # 3. correlation peaks
    if result.clap and result.clap.curves:
        fig, ax = plt.subplots(figsize=(9, 3.4))
        for (i, j, k), (lag_ms, curve) in result.clap.curves.items():
            ax.plot(lag_ms, curve, lw=0.8, label=f"{i}-{j} clap {k}")
        ax.set_xlabel("lag (ms)")
        ax.set_ylabel("GCC-PHAT")
        ax.set_title("correlation peaks around each clap")
        ax.legend(fontsize=6, ncol=2)
        fig.tight_layout()
        paths.append(_save(fig, out / "peaks.png"))
        plt.close(fig)
    # 4. agreement between methods
    pairs = sorted({k for n in names for k in result.camera_diagnostics.get(n, {}).get("agreement_ms", {})})
    if pairs:
        fig, ax = plt.subplots(figsize=(9, 3.4))
        w = 0.8 / len(pairs)
        for p_i, p in enumerate(pairs):
            vals = [result.camera_diagnostics[n].get("agreement_ms", {}).get(p, np.nan) for n in names]
            x = np.arange(len(names)) + p_i * w
            ax.bar(x, vals, w, label=p)
            for xi, v in zip(x, vals):
                if np.isfinite(v):
                    ax.annotate(f"{v:+.3g}", (xi, v), ha="center", va="bottom" if v >= 0 else "top", fontsize=7)
        ax.set_xticks(np.arange(len(names)) + 0.4 - w / 2, names)
        ax.set_yscale("symlog", linthresh=0.01)  # sub-0.01 ms agreement next to whole-frame tmcd
        ax.set_ylabel("difference (ms)")
        ax.set_title("agreement between methods (at the claps, else mid-take)")
        ax.axhline(0, color="k", lw=0.5)
        ax.legend(fontsize=7)
        fig.tight_layout()
        paths.append(_save(fig, out / "agreement.png"))
        plt.close(fig)
    return paths
