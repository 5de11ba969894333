"""Metrics of a workspace's results against its ground truth (gt/), grouped by stage: one
module per stage with ``evaluate(ws) -> dict | None``; stage.py's ``evaluate_workspace`` gathers them."""

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["calibration", "stage"]
