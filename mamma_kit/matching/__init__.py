"""Cross-view identity: tracklet epipolar affinities, per-pair Hungarian assignment and a
cycle-consistent multi-view grouping (`mamma-kit match`)."""
