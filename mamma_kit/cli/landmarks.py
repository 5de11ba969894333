"""`mamma-kit landmarks`: MammaNet landmarks for every tracked person (or noisy ground truth)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from mamma_kit.cli.app import app
from mamma_kit.cli.common import JsonOpt, QuietOpt, emit_json, setup
from mamma_kit.core import log
from mamma_kit.core.errors import UserError


def _cameras(ws, only: Optional[str], fallback_dir: Path | None = None) -> list[str]:
    if ws.capture_toml.is_file():
        names = ws.load_capture().camera_names
    elif fallback_dir is not None and fallback_dir.is_dir():
        names = sorted(p.stem for p in fallback_dir.glob("*.npz"))
    else:
        names = []
    if only:
        want = [c.strip() for c in only.split(",") if c.strip()]
        bad = [c for c in want if c not in names]
        if bad:
            raise UserError(f"unknown camera(s) {', '.join(bad)}", f"cameras in this workspace: {', '.join(names)}")
        names = want
    if not names:
        raise UserError(f"{ws.root} lists no cameras", "check capture.toml")
    return names


@app.command("landmarks")
def landmarks_cmd(
    workspace: Optional[Path] = typer.Argument(None, help="Capture workspace (masks/<cam>.npz + videos)."),
    weights: Optional[Path] = typer.Option(None, "--weights", help="Weights file: a mamma-kit .pt, or the official "
                                                                   "Lightning .ckpt with --arch official."),
    arch: Optional[str] = typer.Option(None, "--arch", help="Architecture: embedded (default), embedded-256, "
                                                            "embedded-single, official, ..."),
    batch: int = typer.Option(8, "--batch", min=1, help="Crops per network batch."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    threads: int = typer.Option(0, "--threads", min=0, help="torch CPU threads (0 = torch's default; 1 is faster "
                                                            "on a machine busy with other jobs)."),
    cameras: Optional[str] = typer.Option(None, "--cameras", help="Comma-separated subset of cameras."),
    source: str = typer.Option("net", "--source", help="net (MammaNet) or gt (noisy ground truth of a synthetic "
                                                       "workspace)."),
    noise: str = typer.Option("0", "--noise", help="--source gt: noise in px, or '1.2%' of the box height."),
    outliers: float = typer.Option(0.0, "--outliers", help="--source gt: fraction of landmarks made outliers."),
    seed: int = typer.Option(0, "--seed", help="--source gt: random seed."),
    describe: bool = typer.Option(False, "--describe", help="Print the architecture's state-dict names and shapes."),
    force: bool = typer.Option(False, "--force", help="Recompute even if inputs are unchanged."),
    json_out: bool = JsonOpt,
    quiet: bool = QuietOpt,
) -> None:
    """Dense landmarks (xy, sigma, visibility, contact, floor contact) for every tracked person and frame."""
    setup(quiet, json_out)
    if describe:
        from mamma_kit.landmarks.config import DEFAULT_ARCH
        from mamma_kit.landmarks.model import state_dict_shapes

        shapes = state_dict_shapes(arch or DEFAULT_ARCH)
        if json_out:
            emit_json([{"name": k, "shape": list(s)} for k, s in shapes])
        else:
            for k, s in shapes:
                typer.echo(f"{k} ({', '.join(map(str, s))}{',' if len(s) == 1 else ''})")
        return
    if source not in ("net", "gt"):
        raise UserError(f"--source '{source}' is unknown", "use --source net or --source gt")
    if device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise UserError("--device cuda but torch sees no CUDA device", "use --device cpu")
    if threads:
        import torch

        torch.set_num_threads(threads)
    from mamma_kit.core.manifest import StageManifest, producer
    from mamma_kit.core.workspace import Workspace

    loaded = None
    if source == "net":  # load (and validate) the weights first: a bad --weights is the first thing to report
        from mamma_kit.landmarks.weights import load_model

        loaded = load_model(weights, arch, device)
    if workspace is None:
        raise UserError("no WORKSPACE given", "run `mamma-kit landmarks WORKSPACE` (or --describe to list the weights)")
    ws = Workspace(workspace)
    t0 = time.perf_counter()
    manifest = StageManifest(ws.cache_dir, "landmarks", ws.root)
    if source == "gt":
        from mamma_kit.landmarks.gt import gt_landmarks_file, gt_masks_file, noisy_gt_landmarks

        cams = _cameras(ws, cameras, ws.gt_dir / "landmarks")
        inputs = [p for c in cams for p in (gt_landmarks_file(ws, c), gt_masks_file(ws, c), ws.mask_file(c))
                  if p.exists()]
        settings = {"source": "gt", "noise": noise, "outliers": outliers, "seed": seed, "cameras": cams}
    else:
        cams = _cameras(ws, cameras)
        cap = ws.load_capture()
        missing = [c for c in cams if not ws.mask_file(c).is_file()]
        if missing:
            raise UserError(f"no person masks for {', '.join(missing)} (masks/<cam>.npz)",
                            "run `mamma-kit track WORKSPACE` first")
        inputs = [ws.mask_file(c) for c in cams] + [cap.cameras[c].video for c in cams] + [Path(loaded.source)]
        settings = {"source": "net", "arch": loaded.config.name, "weights": loaded.source, "cameras": cams}
    outputs = [ws.landmarks_file(c) for c in cams]
    state = manifest.check(inputs, settings)
    if state.fresh and not force and all(p.is_file() for p in outputs):
        log.info(f"landmarks: up to date ({state.reason}); skipped (--force recomputes)")
        summary = {"stage": "landmarks", "skipped": True, "reason": state.reason, "cameras": cams}
        if json_out:
            emit_json(summary)
        return
    hashes = {ws.relative(p): manifest.hasher(p) for p in inputs}
    prod = producer("landmarks " + " ".join(f"{k}={v}" for k, v in settings.items() if k != "cameras"), hashes)
    per_cam = []
    for cam in cams:
        if source == "gt":
            lt, summ = noisy_gt_landmarks(ws, cam, noise, outliers, seed)
            lt.producer = prod
        else:
            from mamma_kit.core.tracks import MaskTracks
            from mamma_kit.landmarks.inference import Predictor, run_camera

            pred = Predictor(loaded, device)
            lt, summ = run_camera(pred, cam, MaskTracks.load(ws.mask_file(cam)), cap.cameras[cam].video, batch,
                                  producer=prod)
        lt.save(ws.landmarks_file(cam))
        per_cam.append(summ)
    secs = time.perf_counter() - t0
    summary = {"stage": "landmarks", "skipped": False, "source": source, "cameras": per_cam, "seconds": round(secs, 2)}
    if loaded is not None:
        summary.update({"arch": loaded.config.name, "weights": loaded.source, "landmark_set": loaded.landmark_set})
    manifest.record(inputs, settings, outputs, summary, secs)
    if json_out:
        emit_json(summary)
    else:
        log.info(f"landmarks written for {len(cams)} camera(s) in {secs:.1f} s")
