"""Metrics of a workspace's results against its ground truth (gt/), grouped by stage.

Each stage has a module here with ``evaluate(ws: Workspace) -> dict | None`` (None when the
workspace holds nothing to evaluate for that stage). ``evaluate_workspace`` gathers them.
"""

from __future__ import annotations

import importlib

from mamma_kit.core.errors import UserError
from mamma_kit.core.workspace import Workspace

# group name -> module; a module appears here once its stage exists
GROUPS = {
    "calibration": "mamma_kit.evaluation.calibration",
    "timing": "mamma_kit.evaluation.timing",
    "masks": "mamma_kit.evaluation.masks",
    "landmarks": "mamma_kit.evaluation.landmarks",
    "identities": "mamma_kit.evaluation.identities",
    "fit": "mamma_kit.evaluation.fit",
}


def available_groups() -> dict[str, object]:
    out = {}
    for name, mod in GROUPS.items():
        try:
            out[name] = importlib.import_module(mod)
        except ModuleNotFoundError as e:
            if e.name != mod:  # a real missing dependency, not a stage that has not landed
                raise
    return out


def evaluate_workspace(ws: Workspace, groups: list[str] | None = None) -> dict:
    """One JSON-able dict: {group: metrics} for every group with something to evaluate."""
    if not ws.gt_dir.is_dir():
        raise UserError(f"{ws.root} has no gt/ folder: only synthetic workspaces can be evaluated",
                        "make one with `mamma-kit synth RECIPE --out DIR`")
    result: dict = {}
    for name, mod in available_groups().items():
        if groups and name not in groups:
            continue
        metrics = mod.evaluate(ws)
        if metrics is not None:
            result[name] = metrics
    return result
