"""Exports: the fitted people in the formats other tools open.

run.py (``export_workspace``, the command's work), motion.py (a result as a skeleton's local
transforms, shared by the animation formats), gltf.py (skinned meshes, cameras, floor), bvh.py,
markers.py with markers.toml (virtual markers on the body surface), trc.py and c3d.py (their
trajectories), amass.py (SMPL-X parameters as AMASS stores them).
"""

__all__ = ["amass", "bvh", "c3d", "gltf", "markers", "motion", "run", "stage", "trc"]
