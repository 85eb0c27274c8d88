"""The one exception type for bad user input."""

from __future__ import annotations

import os


class InputError(ValueError):
    """A user file is malformed or implausible.

    The message is one line, ``"<file>: <field>: <what was wrong and what was expected>"``, so that
    the CLI can print it as-is and a user can act on it without a traceback.
    """

    def __init__(self, source: str | os.PathLike, field: str, message: str):
        self.source = str(source)
        self.field = field
        self.detail = " ".join(str(message).split())  # one line, whatever the caller passed
        super().__init__(f"{self.source}: {field}: {self.detail}")
