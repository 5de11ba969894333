"""Calibration: ChArUco detection, intrinsics, extrinsics + bundle adjustment, diagnostics,
and import/export of other tools' calibration formats (formats.py)."""
