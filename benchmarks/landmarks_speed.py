"""MammaNet speed on this machine: crops/s (inference) and samples/s (training), peak memory.

    nice -n 10 /work/venv/bin/python benchmarks/landmarks_speed.py                 # embedded + official
    nice -n 10 /work/venv/bin/python benchmarks/landmarks_speed.py --arch embedded --arch embedded-256 --train

Each architecture runs in its own subprocess (so peak RSS is per model) with torch threads = --threads
(default 2). Wall-clock figures depend on other jobs on the machine (the load average is printed);
"per CPU-second" figures with --threads 1 do not, and bound what one idle core does. Inference is timed end to end per crop: the crop warp from a 1920x1080 frame and mask
(crop.py contract), normalisation and the network; "net only" excludes the crop. Weights are the
package's trained weights when present, else random ones of the same architecture (said in the
output: speed does not depend on the values).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np


def _one(arch: str, threads: int, batch: int, seconds: float, do_train: bool) -> dict:
    import torch

    torch.set_num_threads(threads)
    from mamma_kit.landmarks.inference import Predictor
    from mamma_kit.landmarks.weights import load_model, random_model
    from mamma_kit.core.errors import UserError

    try:
        loaded, weights = load_model(arch=arch), "trained"
    except UserError:
        loaded, weights = random_model(arch), "random (untrained)"
    pred = Predictor(loaded)
    cfg = loaded.config
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 255, (1080, 1920, 3), dtype=np.uint8)
    mask = np.zeros((1080, 1920), bool)
    mask[200:900, 800:1150] = True  # a 700 px tall person: the crop downscales (anti-aliasing path)

    def crops(n):
        out = [pred.crop(frame, mask) for _ in range(n)]
        return np.stack([c[0] for c in out]), np.stack([c[1] for c in out]), np.stack([c[2] for c in out])

    imgs, masks, boxes = crops(batch)
    pred.predict_crops(imgs, masks)  # warm-up
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds or n == 0:
        imgs, masks, boxes = crops(batch)
        Predictor.to_image(pred.predict_crops(imgs, masks), boxes)
        n += batch
    e2e = n / (time.perf_counter() - t0)
    n, t0, c0 = 0, time.perf_counter(), time.process_time()
    while time.perf_counter() - t0 < seconds or n == 0:
        pred.predict_crops(imgs, masks)
        n += batch
    net = n / (time.perf_counter() - t0)
    net_cpu = n / (time.process_time() - c0)  # crops per CPU-second: robust to other jobs at 1 thread
    t0 = time.perf_counter()
    for _ in range(20):
        crops(1)
    crop_ms = (time.perf_counter() - t0) / 20 * 1000
    res = {"arch": arch, "weights": weights, "parameters": sum(p.numel() for p in loaded.model.parameters()),
           "input_hw": list(cfg.input_hw), "batch": batch, "threads": threads, "crops_per_s": round(e2e, 2),
           "net_only_crops_per_s": round(net, 2), "crops_per_cpu_s": round(net_cpu, 2),
           "crop_ms": round(crop_ms, 2)}
    if do_train and not arch.startswith("official"):  # nobody trains ViT-B on a CPU
        from mamma_kit.landmarks.losses import mammanet_loss
        from mamma_kit.landmarks.model import build_model
        from mamma_kit.landmarks import crop as C

        model = build_model(cfg).train()
        opt = torch.optim.AdamW(model.parameters(), lr=1e-4)
        B = 8
        H, W = cfg.input_hw
        x = C.normalise_images(rng.integers(0, 255, (B, H, W, 3), dtype=np.uint8))
        m = torch.ones(B, 1, H, W)
        L = cfg.n_landmarks
        tgt = {"xy_n": torch.rand(B, L, 2) * 2 - 1, "visibility": torch.ones(B, L), "contact": torch.zeros(B, L),
               "floor_contact": torch.zeros(B, L)}

        def step():
            loss, _ = mammanet_loss(model(x, m), tgt)
            opt.zero_grad()
            loss.backward()
            opt.step()

        step()
        n, t0, c0 = 0, time.perf_counter(), time.process_time()
        while time.perf_counter() - t0 < seconds or n == 0:
            step()
            n += B
        res["train_samples_per_s"] = round(n / (time.perf_counter() - t0), 2)
        res["train_samples_per_cpu_s"] = round(n / (time.process_time() - c0), 2)
    res["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--arch", action="append", help="architectures (default: embedded, official)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--batch", type=int, default=None, help="crops per batch (default 8; 2 for official)")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--train", action="store_true", help="also time training steps (batch 8)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    archs = a.arch or ["embedded", "official"]
    if a.child:
        b = a.batch or (2 if archs[0].startswith("official") else 8)
        print(json.dumps(_one(archs[0], a.threads, b, a.seconds, a.train)))
        return
    import os

    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    print(f"MammaNet speed, {a.threads} torch threads, {a.seconds:.0f} s per measurement, "
          f"load average before: {load} on {os.cpu_count()} cores, OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY', 'unset')}")
    print(f"command: {' '.join(sys.argv)}")
    for arch in archs:
        cmd = [sys.executable, __file__, "--child", "--arch", arch, "--threads", str(a.threads), "--seconds",
               str(a.seconds)] + (["--batch", str(a.batch)] if a.batch else []) + (["--train"] if a.train else [])
        r = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.strip().splitlines()[-1])
        line = (f"{r['arch']:<16} {r['parameters'] / 1e6:7.2f} M params  {r['input_hw'][0]}x{r['input_hw'][1]}  "
                f"batch {r['batch']}: {r['crops_per_s']:7.2f} crops/s end to end (net only {r['net_only_crops_per_s']:.2f}, "
                f"crop {r['crop_ms']:.1f} ms from 1080p)")
        line += f"; {r['crops_per_cpu_s']:.2f} crops per CPU-second"
        if "train_samples_per_s" in r:
            line += (f"; training {r['train_samples_per_s']:.2f} samples/s "
                     f"({r['train_samples_per_cpu_s']:.2f} per CPU-second)")
        line += f", peak RSS {r['peak_rss_mb']:.0f} MB, weights: {r['weights']}"
        print(line, flush=True)
    print(f"load average after: {', '.join(f'{v:.1f}' for v in os.getloadavg())} (other work on the machine slows "
          f"every figure; compare runs at similar load)")


if __name__ == "__main__":
    main()
