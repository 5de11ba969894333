"""One colour per person id, the same in the report's figures and overlays and in exports."""

from __future__ import annotations


def person_colour(pid: int) -> tuple[float, float, float]:
    """One RGB colour in [0, 1] per person id (matplotlib's tab10, cycling)."""
    import matplotlib

    return tuple(matplotlib.colormaps["tab10"](int(pid) % 10)[:3])
