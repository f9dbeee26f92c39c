"""The one user-facing error type of drivee2e-jax.

Raise :class:`DriveE2EError` for anything a *user* can fix (a bad file, an
unknown suite name, a missing split, an option out of range). Its ``str`` is a
single line that names what is wrong and what was expected; the CLI prints it
as ``drivee2e: error: <message>`` with exit code 2 and no traceback (unless
``--debug``). Bugs stay ordinary exceptions so they keep their traceback.
"""

from __future__ import annotations


def one_line(text: object, limit: int | None = None) -> str:
    """``str(text)`` with every run of whitespace (newlines too) folded into
    one space; longer than ``limit`` characters: cut to ``limit``, ending
    "...". What every one-line message about an exception or a value uses."""
    line = " ".join(str(text).split())
    if limit is not None and len(line) > limit:
        line = line[:limit - 3] + "..."
    return line


class DriveE2EError(Exception):
    """A user-facing error whose ``str`` is a one-line message.

    Newlines in the message are folded into spaces so that the CLI's promise of
    "one line on stderr" holds whatever the caller passes.
    """

    def __init__(self, message: str):
        super().__init__(one_line(message))

    @property
    def message(self) -> str:
        return self.args[0]
