"""Cross-view identity: tracklet epipolar affinities, per-pair Hungarian assignment and a
cycle-consistent multi-view grouping (`mamma-kit match`)."""

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["pictures", "stage"]
