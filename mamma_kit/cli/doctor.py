"""`mamma-kit doctor`: what is installed, what is available, and what to do about the rest."""

from __future__ import annotations

import importlib
import importlib.metadata as md
import platform

import typer

from mamma_kit import __version__
from mamma_kit.cli.common import JsonOpt, emit_json
from mamma_kit.cli.root import app
from mamma_kit.core import log
from mamma_kit.core.doctor import check as _check

CORE_PACKAGES = ["numpy", "scipy", "torch", "opencv-contrib-python-headless", "av", "librosa", "soundfile",
                 "trimesh", "embreex", "typer", "rich", "tomli-w", "pyyaml", "matplotlib"]
OPTIONAL_PACKAGES = {
    "smplx": "pip install smplx  (only for cross-checks; mamma-kit reads SMPL-X .npz files itself)",
    "sam2": "pip install sam2 and pass --sam2-checkpoint to `mamma-kit track --backend sam2`",
    "rerun-sdk": "pip install rerun-sdk to export Rerun recordings from `mamma-kit report`",
}


def _version_of(dist: str) -> str | None:
    try:
        return md.version(dist)
    except md.PackageNotFoundError:
        return None


def run_checks() -> dict:
    """Gather versions and capability checks into one JSON-able dict."""
    packages = {d: _version_of(d) for d in CORE_PACKAGES}
    optional = {d: _version_of(d) for d in OPTIONAL_PACKAGES}
    checks = []
    missing = [d for d, v in packages.items() if v is None]
    checks.append(_check("core packages", not missing, "all installed" if not missing else f"missing: {missing}",
                         "reinstall mamma-kit: pip install -e ."))
    try:
        import torch

        checks.append(_check("torch", True, f"{torch.__version__}, threads {torch.get_num_threads()}, "
                                            f"cuda {'yes' if torch.cuda.is_available() else 'no'}"))
    except Exception as e:  # noqa: BLE001 - report any import failure
        checks.append(_check("torch", False, str(e), "pip install torch==2.13.0"))
    try:
        import cv2

        ok = hasattr(cv2, "aruco") and hasattr(cv2.aruco, "CharucoDetector")
        checks.append(_check("opencv aruco", ok, f"cv2 {cv2.__version__}",
                             "install opencv-contrib-python-headless (not opencv-python)"))
    except Exception as e:  # noqa: BLE001
        checks.append(_check("opencv aruco", False, str(e), "pip install opencv-contrib-python-headless"))
    try:
        import av

        codecs = av.codecs_available
        ok = "libx264" in codecs and "aac" in codecs
        checks.append(_check("video codecs", ok, f"PyAV {av.__version__}: libx264 {'libx264' in codecs}, "
                                                 f"aac {'aac' in codecs}", "install PyAV wheels from PyPI"))
    except Exception as e:  # noqa: BLE001
        checks.append(_check("video codecs", False, str(e), "pip install av"))
    try:
        from trimesh.ray import has_embree

        checks.append(_check("embree ray casting", bool(has_embree), "trimesh + embreex",
                             "pip install embreex (rendering is unusably slow without it)"))
    except Exception as e:  # noqa: BLE001
        checks.append(_check("embree ray casting", False, str(e), "pip install embreex"))
    checks.extend(_stage_checks())
    for dist, fix in OPTIONAL_PACKAGES.items():
        v = optional[dist]
        checks.append({"name": f"optional: {dist}", "ok": v is not None, "optional": True,
                       "detail": v or "not installed", **({"fix": fix} if v is None else {})})
    return {
        "mamma_kit": __version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "packages": packages,
        "optional_packages": optional,
        "checks": checks,
        "ok": all(c["ok"] for c in checks if not c.get("optional")),
    }


def _stage_checks() -> list[dict]:
    """Checks contributed by stages (body model, MammaNet weights, ...), when present."""
    out = []
    for mod in ("mamma_kit.body.doctor", "mamma_kit.landmarks.doctor"):
        try:
            m = importlib.import_module(mod)
        except ModuleNotFoundError:
            continue
        out.extend(m.checks())
    return out


@app.command(rich_help_panel="Tools")
def doctor(json_out: bool = JsonOpt) -> None:
    """Show versions, available body models and weights, and how to fix what is missing."""
    report = run_checks()
    if json_out:
        emit_json(report)
        return
    typer.echo(f"mamma-kit {report['mamma_kit']}  (Python {report['python']}, {report['platform']})")
    for c in report["checks"]:
        mark = "ok " if c["ok"] else ("-- " if c.get("optional") else "!! ")
        line = f"  {mark} {c['name']}: {c['detail']}"
        if not c["ok"] and c.get("fix"):
            line += f"  -> {c['fix']}"
        typer.echo(line)
    if not report["ok"]:
        log.warn("some required checks failed; see the lines marked !!")
        raise typer.Exit(1)
