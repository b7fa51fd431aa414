"""Ctrl-C at a safe point: a long computation asks :func:`requested` between its chunks.

A ``KeyboardInterrupt`` raised at a random point can land inside a callback that swallows
it (JAX's garbage-collection hook does), and the command then runs on as if nothing had
been pressed. Inside :func:`deferred`, the first Ctrl-C only sets a flag that the engine
reads after each chunk, where it raises ``KeyboardInterrupt`` itself; a second Ctrl-C
interrupts at once, as usual.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Iterator

_pressed = threading.Event()


def requested() -> bool:
    """Whether Ctrl-C was pressed inside :func:`deferred`."""
    return _pressed.is_set()


def check() -> None:
    """Raise ``KeyboardInterrupt`` here if Ctrl-C was pressed."""
    if _pressed.is_set():
        raise KeyboardInterrupt


@contextmanager
def deferred() -> Iterator[None]:
    """Defer Ctrl-C to the next :func:`check` (main thread only; elsewhere a no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _pressed.clear()

    def on_sigint(signum, frame):
        _pressed.set()
        signal.signal(signal.SIGINT, previous)  # a second Ctrl-C interrupts at once

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        pressed = _pressed.is_set()
        _pressed.clear()
    if pressed:  # pressed after the last check: never lost
        raise KeyboardInterrupt
