"""The workspace the real-recording benchmarks share: ../shared/real/pose2sim-multiperson with its
Qualisys calibration (`init --calibration --synced`, two people), made once in ROOT/ws and reused.

    from real_workspace import real_workspace
    ws = real_workspace(root, stages=True)   # + `track --backend pose --people 2` and `keypoints`
"""

from __future__ import annotations

from pathlib import Path

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real" / "pose2sim-multiperson"


def real_workspace(root: Path, stages: bool = False, force: bool = False, videos: list[Path] | None = None):
    """The Workspace in root/ws; with ``stages``, its pose tracks and keypoints are (re)made as needed.
    ``videos``: other files of the same four cameras (e.g. phone-stored copies) instead of the originals."""
    from mamma_kit.cli.app import main as cli
    from mamma_kit.core import log
    from mamma_kit.core.workspace import Workspace
    from mamma_kit.pipeline import init_workspace

    log.set_quiet(True)
    ws_path = Path(root) / "ws"
    if not (ws_path / "capture.toml").is_file():
        init_workspace(ws_path, videos or sorted((REAL / "videos").glob("cam*.mp4")),
                       calibration=REAL / "calibration" / "Calib.qca.txt", people=2, synced=True)
    if stages:
        for cmd in (["track", str(ws_path), "--backend", "pose", "--people", "2"], ["keypoints", str(ws_path)]):
            try:
                cli([*cmd, "--quiet", *(["--force"] if force else [])])
            except SystemExit as e:
                if e.code not in (0, None):
                    raise
    return Workspace(ws_path)
