"""Calibration: ChArUco detection, intrinsics, extrinsics + bundle adjustment, diagnostics,
and import/export of other tools' calibration formats (formats.py)."""

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["board", "formats", "lens", "people", "stage"]
