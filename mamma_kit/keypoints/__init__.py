"""Real-world person perception: BlazePose GHUM (full) on LiteRT, shipped with the package.

``estimator.PoseEstimator`` finds people and their 33 points (and a mask) in a frame;
``stage.run_keypoints`` writes keypoints/<cam>.npz for every tracked person.
"""
