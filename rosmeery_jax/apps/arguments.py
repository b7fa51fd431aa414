"""Checks and help texts the ``rosmeery`` sub-commands share."""

from __future__ import annotations

import argparse

from rosmeery_jax.core import specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.detector.detections import WEIGHTS

WEIGHTS_HELP = f"a file, or the name of shipped weights: {', '.join(WEIGHTS)} (default: {next(iter(WEIGHTS))})"


def positive(args, *names: str) -> None:
    """Whole-number options that must be >= 1 (a seed from 0 to MAX_SEED, as results hold
    seeds); None is unset."""
    for name in names:
        value, least = getattr(args, name), 0 if name == "seed" else 1
        if value is not None and value < least:
            raise InputError("command line", "--" + name.replace("_", "-"), f"{value} must be a whole number >= {least}")
        if name == "seed" and value is not None and value > specs.MAX_SEED:  # an OverflowError in teleop
            raise InputError("command line", "--seed", f"{value} must be at most {specs.MAX_SEED}")


def int_list(text: str) -> tuple[int, ...]:
    """An argparse type: a comma-separated list of whole numbers >= 1 (batch sizes)."""
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of integers") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: batch sizes must be >= 1")
    return values
