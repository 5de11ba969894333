"""Synchronisation: every camera's clock model (t_ref = (1 + rate) t_cam + offset) from claps
(onsets + GCC-PHAT), LTC timecode on an audio channel, or the tmcd start timecode; a joint
solve over all cameras, diagnostics, and a per-reference-time frame timeline."""

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["crosscheck", "stage"]
