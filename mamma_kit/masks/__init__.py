"""Person mask tracks per view (`mamma-kit track`): backends behind one interface.

- ``builtin``: no weights; static background model, shadow-robust foreground, instances,
  tracking with stable ids through crossings (masks/builtin.py).
- ``sam2``: the `sam2` package with the user's checkpoint, in bounded chunks (masks/sam2.py).
- ``gt``: the ground-truth masks of a synthetic workspace (masks/gt.py).
"""

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["pose", "stage"]
