"""The builtin backend's settings: one dataclass shared by its pixel functions (segment.py),
its tracker (tracker.py) and the backend itself (builtin.py)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class BuiltinSettings:
    max_side: int = 960  # working resolution (longest side, px)
    bg_samples: int = 40
    chroma_k: float = 5.0  # chromatic distortion / noise above which a pixel is foreground
    bright_k: float = 6.0  # brightness change / noise above which a brighter pixel is foreground
    shadow_alpha: float = 0.5  # darker than this fraction of the background: not a shadow
    chroma_angle: float = 0.08  # chromatic distortion relative to brightness that marks a new colour
    noise_floor: float = 2.5  # grey levels
    min_area_frac: float = 4e-4  # of the image area: smaller components are noise
    link_frac: float = 0.012  # fragments closer than this fraction of the image height are one instance
    new_track_area_frac: float = 8e-4
    border_area_factor: float = 0.5  # new tracks touching the image border need this share of that area
    claim_frac: float = 0.15  # a prediction claims a component holding this much of it
    occluded_frac: float = 0.12  # a track given less than this fraction of its predicted area is occluded
    colour_weight: float = 1.0
    colour_smooth_frac: float = 0.006  # splitting touching people: colour evidence over this fraction of the height
    # splitting people who stand apart (axes >= axis_separation widths apart): a pixel's horizontal
    # distance to each one's axis (segment.body_axes) weighs this much beside its distance to the
    # prediction (0: off). The duo's renders, masks IoU with axis_weight 0 -> 0.5: seed 11 (matching
    # black shirts) 0.722 -> 0.852, demo 0.880 -> 0.894, seed 7 0.883 -> 0.911; the crowds about even
    # (benchmarks/masks_quality.py)
    axis_weight: float = 0.5
    axis_separation: float = 1.0
    max_lost: int = 45  # frames a lost track can be re-identified
    # a track that parts from another (two people who came in as one blob) is followed back this many
    # frames, splitting the blob they shared there (0: off)
    backfill_frames: int = 90
    reid_similarity: float = 0.5  # Bhattacharyya coefficient needed to re-identify a lost track
    velocity_smoothing: float = 0.5
    people: int | None = None  # how many people the capture shows (splits blobs of people side by side)
    use_board_plate: bool = True  # background from the camera's board video when it shows the same scene
    plate_max_differ: float = 0.35  # fraction of the image where plate and capture may differ (people)
    edge_coverage: float = 0.5  # rim pixels are the person's if it covers this fraction of them (0: off)
    max_hole_frac: float = 2e-4  # holes larger than this fraction of the image stay open in the masks (0: fill all)
