"""Fitting SMPL-X bodies to multi-view landmarks: the four-stage fit with contact.

- stage.py: ``fit_workspace(ws, ...)``, the workspace runner (smplx/ and fit_report.json).
- stages.py: ``Fitter`` / ``FitConfig`` to fit FitData directly (tests, benchmarks).
- cameras.py: ``pick_cameras(rig, count)``, farthest-point sampling of cameras.
"""

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["cameras", "checks", "contact", "data", "stage", "stages"]
