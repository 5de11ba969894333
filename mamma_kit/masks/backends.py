"""The mask backends by name: ``get_backend(name, **options)`` builds one.

Each backend module imports base.py for the shared types; this registry sits above them all, so
nothing imports in a circle. A backend is imported only when asked for (sam2 needs its package).
"""

from __future__ import annotations

from mamma_kit.core.errors import UserError
from mamma_kit.masks.base import MaskBackend

BACKENDS = ("builtin", "pose", "sam2", "gt")


def get_backend(name: str, **options) -> MaskBackend:
    if name == "builtin":
        from mamma_kit.masks.builtin import BuiltinBackend

        return BuiltinBackend(**{k: v for k, v in options.items() if k in ("settings",)})
    if name == "pose":
        from mamma_kit.masks.pose import PoseBackend

        return PoseBackend()
    if name == "gt":
        from mamma_kit.masks.gt import GtBackend

        return GtBackend()
    if name == "sam2":
        from mamma_kit.masks.sam2 import Sam2Backend

        return Sam2Backend(**options)
    raise UserError(f"unknown mask backend '{name}'", f"use one of {', '.join(BACKENDS)}")
