"""`mamma-kit STAGE ...` in its own process, timed: what the benchmarks that report a stage's time and
peak memory share.

    from stage_process import run_stage
    seconds, peak_mb = run_stage(["match", str(ws), "--force", "--quiet"])
"""

from __future__ import annotations

import json
import subprocess
import sys

# A process forked from a large one starts with that one's resident size as its peak (Linux keeps
# ru_maxrss across fork and exec), so a benchmark that has grown (scoring a take, rendering) would
# see its own size in every stage's figure. Stages are started by this small launcher instead, a
# fresh interpreter that imports nothing else.
_LAUNCHER = r"""
import json, os, subprocess, sys, time
answers = os.fdopen(int(sys.argv[1]), "w")  # the stages' own output goes where the benchmark's does
for line in sys.stdin:
    req = json.loads(line)
    t0 = time.perf_counter()
    p = subprocess.Popen(req["argv"], env=req["env"])
    _, status, usage = os.wait4(p.pid, 0)
    print(json.dumps([os.waitstatus_to_exitcode(status), time.perf_counter() - t0, usage.ru_maxrss / 1024]),
          file=answers, flush=True)
"""
_launcher: dict = {}


def run_stage(args: list[str], env: dict | None = None) -> tuple[float, float]:
    """Wall seconds and peak resident memory (MB) of `mamma-kit ARGS`, in a process of its own
    (ru_maxrss: the largest single process among the stage and the workers it waited for)."""
    import os

    proc = _launcher.get("proc")
    if proc is None or proc.poll() is not None:
        r, w = os.pipe()
        proc = _launcher["proc"] = subprocess.Popen([sys.executable, "-c", _LAUNCHER, str(w)], stdin=subprocess.PIPE,
                                                    pass_fds=(w,), text=True)
        os.close(w)
        _launcher["answers"] = os.fdopen(r)
    proc.stdin.write(json.dumps({"argv": [sys.executable, "-m", "mamma_kit", *args],
                                 "env": dict(env if env is not None else os.environ)}) + "\n")
    proc.stdin.flush()
    code, secs, peak_mb = json.loads(_launcher["answers"].readline())
    if code:
        raise RuntimeError(f"mamma-kit {' '.join(args)} failed ({code})")
    return round(secs, 1), round(peak_mb, 0)
