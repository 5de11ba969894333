"""Real-world person perception: BlazePose GHUM (full) on LiteRT, shipped with the package.

``estimator.PoseEstimator`` finds people and their 33 points (and a mask) in a frame;
``stage.run_keypoints`` writes keypoints/<cam>.npz for every tracked person; ``resplit`` gives
touching people's pixels to the skeleton they belong to (the stage reads those people again).
"""

# the submodules other packages may import (tests/test_architecture.py holds them to it)
__all__ = ["blazepose", "estimator", "resplit", "runtime", "stage"]
