"""Entry point of the `mamma-kit` command line: every command on the root app, and ``main``.

User errors (:class:`~mamma_kit.core.errors.UserError`) end in one line on stderr and exit
code 2; interrupted runs exit 130 with what was finished kept on disk.
"""

from __future__ import annotations

import sys

# Each command module adds its commands to root.app; import order = order in --help.
from mamma_kit.cli import calib, demo, doctor, eval, synth  # noqa: F401
from mamma_kit.cli import sync  # noqa: F401
from mamma_kit.cli import body  # noqa: F401
from mamma_kit.cli import landmarks, train  # noqa: F401
from mamma_kit.cli import keypoints, match, track  # noqa: F401
from mamma_kit.cli import board, calibrate  # noqa: F401
from mamma_kit.cli import fit, report  # noqa: F401
from mamma_kit.cli import pipeline  # noqa: F401
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
