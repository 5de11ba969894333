"""mamma-kit: markerless multi-person motion capture with consumer cameras."""

import os as _os

__version__ = "0.1.0"

# OpenMP threads that spin while waiting made torch 4x slower on a shared 2-core machine;
# passive waiting costs nothing when the cores are free. Must be set before torch loads.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
