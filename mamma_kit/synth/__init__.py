"""Synthetic captures from recipes (scenes, motions, renderer, audio and timecode, board
videos) and MammaNet training crops."""

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["capture", "crops"]
