"""The place stage: the fitted bodies placed in the views that lost them (silhouettes: what a
camera sees of each body, their z-buffer; stage: who is placed or named, the workspace runner,
place/)."""

__all__ = ["silhouettes", "stage"]
