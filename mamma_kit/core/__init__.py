"""Shared types, file formats, workspace paths, caching and errors used by every stage."""

from mamma_kit.core.errors import UserError
from mamma_kit.core.camera import Camera, Rig
from mamma_kit.core.clock import ClockModel

__all__ = ["UserError", "Camera", "Rig", "ClockModel"]
