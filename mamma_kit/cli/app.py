"""Entry point of the `mamma-kit` command line: every command on the root app, and ``main``.

User errors (:class:`~mamma_kit.core.errors.UserError`) end in one line on stderr and exit
code 2; interrupted runs exit 130 with what was finished kept on disk.
"""

from __future__ import annotations

import sys

# Each command module adds its commands to root.app; within a help panel, the order of
# registration is the order in --help: the pipeline's order, then the tools.
from mamma_kit.cli import pipeline, demo  # noqa: F401  (init, capture-to-smplx, demo)
from mamma_kit.cli import board, calibrate, sync, track, keypoints, landmarks, match, fill  # noqa: F401
from mamma_kit.cli import synth, eval, train  # noqa: F401  (before fit: its pick-cameras is a tool)
from mamma_kit.cli import fit, place, report, export  # noqa: F401
from mamma_kit.cli import doctor, calib, body  # noqa: F401
from mamma_kit.cli.root import app
from mamma_kit.core.errors import UserError


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app, turning user errors into one line + exit 2."""
    from mamma_kit.core.reproducible import configure

    configure()  # same inputs, same numbers: deterministic kernels, one BLAS thread
    try:
        app(args=argv, prog_name="mamma-kit", standalone_mode=True)
    except UserError as e:
        sys.stderr.write(f"mamma-kit: error: {e.line()}\n")
        sys.exit(e.exit_code)
    except KeyboardInterrupt:
        sys.stderr.write("mamma-kit: interrupted; finished work is kept, run the command again to resume.\n")
        sys.exit(130)


if __name__ == "__main__":
    main()
