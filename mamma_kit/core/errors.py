"""The one error type a user can cause.

The CLI turns a :class:`UserError` into one line on stderr (what is wrong, what to do)
and exit code 2. Anything else is a bug and may show a traceback.
"""

from __future__ import annotations


class UserError(Exception):
    """Bad input the user can fix: missing file, wrong board spec, corrupt video, ...

    ``message`` says what is wrong; ``hint`` says what to do about it.
    """

    exit_code = 2

    def __init__(self, message: str, hint: str | None = None):
        self.message = message.rstrip(". ")
        self.hint = hint
        super().__init__(self.line())

    def line(self) -> str:
        """One line: the problem, then what to do."""
        text = self.message
        if self.hint:
            text += f"; {self.hint.rstrip('.')}"
        return " ".join(text.split()) + "."


def require_file(path, what: str = "file", hint: str | None = None):
    """Return ``Path(path)`` if it is an existing file, else raise a UserError naming it."""
    from pathlib import Path

    p = Path(path)
    if not p.exists():
        raise UserError(f"{what} not found: {p}", hint or "check the path")
    if not p.is_file():
        raise UserError(f"{what} is not a file: {p}", hint or "pass a file, not a folder")
    return p
