"""Clock models: how a camera's time maps to the reference clock.

t_ref = (1 + rate) * t_cam + offset   (shared/DESIGN.md). ``rate`` is dimensionless
(reported in ppm); ``offset`` in seconds; ``confidence`` in [0, 1]; ``source`` names the
signal it was found from (clap, ltc, tmcd, identity, gt, ...).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np


@dataclass
class ClockModel:
    offset: float = 0.0
    rate: float = 0.0
    source: str = "identity"
    confidence: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def rate_ppm(self) -> float:
        return self.rate * 1e6

    def to_ref(self, t_cam):
        """Camera time(s) -> reference time(s)."""
        return (1.0 + self.rate) * np.asarray(t_cam, float) + self.offset

    def to_cam(self, t_ref):
        """Reference time(s) -> camera time(s)."""
        return (np.asarray(t_ref, float) - self.offset) / (1.0 + self.rate)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["rate_ppm"] = self.rate_ppm
        d["offset_s"] = d.pop("offset")
        d.pop("rate")
        if not d["extra"]:
            d.pop("extra")
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ClockModel":
        offset = d.get("offset_s", d.get("offset", 0.0))
        rate = d["rate_ppm"] * 1e-6 if "rate_ppm" in d else d.get("rate", 0.0)
        return cls(offset=float(offset), rate=float(rate), source=str(d.get("source", "unknown")),
                   confidence=float(d.get("confidence", 0.0)), extra=dict(d.get("extra", {})))
