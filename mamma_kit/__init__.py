"""mamma-kit: markerless multi-person motion capture with consumer cameras."""

__version__ = "0.1.0"
