"""The library's exception types, in the lowest layer that raises them.

`InputError` is bad user input (a file, a setting, an argument); `SimulationError` is a
recording the model cannot follow (almost every simulation failed). Callers catch them by
type; the CLI prints either as one line and exits with status 2.
"""

from __future__ import annotations

import os


class InputError(ValueError):
    """A user file, setting or argument is malformed or implausible.

    The message is one line, ``"<file>: <field>: <what was wrong and what was expected>"``, so that
    the CLI can print it as-is and a user can act on it without a traceback.
    """

    def __init__(self, source: str | os.PathLike, field: str, message: str):
        self.source = str(source)
        self.field = field
        self.detail = " ".join(str(message).split())  # one line, whatever the caller passed
        super().__init__(f"{self.source}: {field}: {self.detail}")


class SimulationError(ValueError):
    """Too few simulations succeeded to go on: nearly every draw left the model's domain
    (the car stopped or reversed, or the state became non-finite).

    Raised by `vdsbi.inference.identify` before training on what is left; `vdsbi.api.identify`
    turns it into an `InputError` about the recording's window.

    Attributes:
        num_usable: simulations that can be trained on, in all rounds so far.
        num_simulated: simulations run in the round that fell short.
    """

    def __init__(self, num_usable: int, num_simulated: int):
        self.num_usable = int(num_usable)
        self.num_simulated = int(num_simulated)
        super().__init__(
            f"only {self.num_usable} usable simulation(s) after a round of {self.num_simulated}; "
            "the others left the model's domain or were not finite"
        )
