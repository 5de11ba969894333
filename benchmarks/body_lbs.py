"""Forward+backward time of the body model's LBS for 2 people x 100 frames.

    nice -n 10 python benchmarks/body_lbs.py [--body-model open] [--threads 2] [--repeats 20]

Restricted = the 512 landmark vertices + 55 joints (the fit's inner loop), with sparse and
dense skinning blends; full = every vertex. The loss is a plain sum of squares so the
figure is the body model's own cost. With smplx installed it also times smplx.SMPLX
(full mesh, the only path it has) on the same parameters.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch

from mamma_kit.body.lbs import pose_mesh, pose_mesh_np, pose_restricted
from mamma_kit.body.model import load_body_model


def _params(P: int, T: int, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    r = lambda *s, sc=0.3: (sc * torch.randn(*s, generator=g)).requires_grad_(True)  # noqa: E731
    return {"betas": r(P, 1, 16, sc=1.0), "global_orient": r(P, T, 3), "body_pose": r(P, T, 63),
            "left_hand_pose": r(P, T, 45), "right_hand_pose": r(P, T, 45), "jaw_pose": r(P, T, 3),
            "leye_pose": r(P, T, 3), "reye_pose": r(P, T, 3), "transl": r(P, T, 3, sc=1.0)}


def _time(fn, repeats: int) -> tuple[float, float, float]:
    """Median wall ms, best wall ms, median process CPU ms (CPU time is what a busy shared
    machine distorts least: wall time also counts waiting for other jobs)."""
    for _ in range(3):
        fn()
    ts, cs = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return statistics.median(ts) * 1e3, min(ts) * 1e3, statistics.median(cs) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--body-model", default="open")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--people", type=int, default=2)
    ap.add_argument("--frames", type=int, default=100)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    m = load_body_model(a.body_model)
    p = _params(a.people, a.frames)
    m.restricted()  # build the gathered landmark data once, as the fit does

    def restricted(sparse: bool):
        def run():
            v, j = pose_restricted(m, p, sparse=sparse)
            ((v ** 2).sum() + (j ** 2).sum()).backward()
        return run

    def full():
        v, j = pose_mesh(m, p)
        ((v ** 2).sum() + (j ** 2).sum()).backward()

    def restricted_fwd():
        with torch.no_grad():
            pose_restricted(m, p)

    print(f"body model {m.name} ({m.num_vertices} vertices), {a.people} people x {a.frames} frames, "
          f"torch {torch.__version__}, {a.threads} threads, load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores; wall median / best and CPU median of {a.repeats} runs")
    p_np = {k: v.detach()[0].numpy() for k, v in p.items()}  # one person's 100 frames, numpy
    rows = [("restricted 512+55, sparse gather, fwd+bwd", restricted(True)),
            ("restricted 512+55, default,  fwd+bwd", restricted(False)),
            ("restricted 512+55, default, fwd only", restricted_fwd),
            ("full mesh,                 fwd+bwd", full),
            ("full mesh numpy, 1 person x frames, no grad", lambda: pose_mesh_np(m, p_np))]
    for name, fn in rows:
        med, best, cpu = _time(fn, a.repeats if "full" not in name else max(3, a.repeats // 4))
        print(f"  {name}: {med:8.2f} ms  (best {best:.2f}, CPU {cpu:.2f})")
    try:
        import smplx  # optional, MPI licence: only as a reference figure
    except ImportError:
        print("  smplx not installed: no reference figure")
        return
    if m.path is None:
        return
    sm = smplx.SMPLX(str(m.path), ext="npz", num_betas=16, use_pca=False, flat_hand_mean=True,
                     batch_size=a.people * a.frames)
    if m.extra_joint_ids is not None:
        sm.vertex_joint_selector.extra_joints_idxs = torch.as_tensor(m.extra_joint_ids)
    flat = {k: v.expand(a.people, a.frames, v.shape[-1]).reshape(-1, v.shape[-1]) for k, v in p.items()}

    def ref():
        o = sm(**flat, expression=torch.zeros(a.people * a.frames, sm.num_expression_coeffs))
        ((o.vertices[:, m.landmark_ids] ** 2).sum() + (o.joints[:, :55] ** 2).sum()).backward()

    med, best, cpu = _time(ref, max(3, a.repeats // 4))
    print(f"  smplx.SMPLX full mesh (peer), fwd+bwd: {med:8.2f} ms  (best {best:.2f}, CPU {cpu:.2f})")


if __name__ == "__main__":
    main()
