"""Command-line programs: the ``rosmeery`` command (:mod:`.cli`), the bench, recording,
teleoperation."""

import os
import sys

from rosmeery_jax.core import interrupt

LONG_COMMANDS = ("run", "train")  # Ctrl-C is deferred to their safe points (core.interrupt)


def main(argv: list[str] | None = None) -> int:
    """The ``rosmeery`` entry point. For a session or a training run, Ctrl-C is deferred from
    the very start, imports included (it could otherwise land in JAX's garbage-collection
    callback, be swallowed, and the run go on): the command stops at its next safe point."""
    args = sys.argv[1:] if argv is None else argv
    command = next((a for a in args if not a.startswith("-")), None)
    if command not in LONG_COMMANDS:
        from rosmeery_jax.apps.cli import main as cli  # imported here: after the deferral, for long commands

        return cli(args)
    try:
        with interrupt.deferred():
            from rosmeery_jax.apps.cli import main as cli

            status = cli(args)
    except KeyboardInterrupt:
        print("rosmeery: interrupted" + (" (finished runs are kept: the same command with --resume continues)"
                                         if command == "run" else ""), file=sys.stderr)
        status = 130
    if status == 130 and interrupt.busy():  # a compile still running in C++ would abort the interpreter's exit
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    return status
