"""Root of the `mamma-kit` command line.

User errors (:class:`~mamma_kit.core.errors.UserError`) end in one line on stderr and exit
code 2; interrupted runs exit 130 with what was finished kept on disk.
"""

from __future__ import annotations

import sys
from typing import Optional

import typer

from mamma_kit import __version__
from mamma_kit.core.errors import UserError

app = typer.Typer(
    name="mamma-kit",
    help="Markerless multi-person motion capture with consumer cameras: calibrate, sync, "
         "track, landmarks, match and fit SMPL-X bodies (the MAMMA method).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"mamma-kit {__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                                 help="Print the version and exit.")) -> None:
    """mamma-kit: from phone videos and a printed ChArUco board to SMPL-X bodies."""


def _register() -> None:
    # Each command module adds its commands to `app`; import order = order in --help.
    from mamma_kit.cli import calib, demo, doctor, eval, synth  # noqa: F401
    from mamma_kit.cli import sync  # noqa: F401
    from mamma_kit.cli import body  # noqa: F401
    from mamma_kit.cli import landmarks, train  # noqa: F401
    from mamma_kit.cli import keypoints, match, track  # noqa: F401
    from mamma_kit.cli import board, calibrate  # noqa: F401
    from mamma_kit.cli import fit, report  # noqa: F401
    from mamma_kit.cli import pipeline  # noqa: F401


_register()


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app, turning user errors into one line + exit 2."""
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
