"""One error type for bad user input.

Every problem with a file the user handed us (world, config, weights, recording, map)
raises :class:`InputError`. Its message is one line that names the file and the field or
element; the CLI prints exactly that line and exits with status 2.
"""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad user input; ``str(err)`` is one line naming the file and the field."""

    def __init__(self, source: str | Path, where: str, problem: str):
        self.source = str(source)
        self.where = where
        self.problem = problem
        location = f"{self.source}: {where}" if where else self.source
        super().__init__(f"{location}: {problem}".replace("\n", " "))

    def __reduce__(self):  # pickled whole, as a Ray task's error reaches the driver
        return type(self), (self.source, self.where, self.problem)


def one_line(main, *args):
    """Run a script's ``main(*args)``: bad input ends it with one line on stderr and exit
    status 1, not a traceback."""
    try:
        return main(*args)
    except InputError as err:
        raise SystemExit(f"error: {err}") from None


def shown(cell) -> str:
    """A value from a user's table as the file has it: text quoted, a number as written
    (``1e+308``, not numpy's ``np.float64(1e+308)``)."""
    return repr(cell) if isinstance(cell, str) else str(cell)
