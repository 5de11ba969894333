"""The root Typer object of the `mamma-kit` command line, and its --version.

Every command module adds its commands to ``app`` here; cli/app.py imports them all (their
order there is the order in --help) and runs it. This module imports no command module.
"""

from __future__ import annotations

import typer

from mamma_kit import __version__

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
                                                 help="Print the version and exit."),
          executor: str = typer.Option(None, "--executor", metavar="local|ray",
                                       help="Where units of work run: local processes, or Ray (MAMMA_KIT_RAY_ADDRESS, "
                                            "else a Ray instance here). Default: MAMMA_KIT_EXECUTOR, else "
                                            "capture.toml's \\[settings] executor, else local."),
          workers: int = typer.Option(None, "--workers", min=1, metavar="N",
                                      help="Units of work side by side (local processes, or Ray tasks in flight). "
                                           "Default: MAMMA_KIT_WORKERS, else one per CPU. The results do not "
                                           "depend on it.")) -> None:
    """mamma-kit: from phone videos and a printed ChArUco board to SMPL-X bodies."""
    from mamma_kit.core.executor import set_executor, set_workers

    set_executor(executor)
    set_workers(workers)
