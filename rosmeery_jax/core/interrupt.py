"""Ctrl-C at a safe point: a long computation asks :func:`check` between its chunks.

A ``KeyboardInterrupt`` raised at a random point can land inside a callback that swallows
it (JAX's garbage-collection hook does), and the command then runs on as if nothing had
been pressed. Inside :func:`deferred`, the first Ctrl-C only sets a flag that the engine
reads between chunks (and while it waits for a compile), where it raises
``KeyboardInterrupt`` itself; a press after the last check is raised when the block ends,
and a second Ctrl-C interrupts at once, as usual.
"""

from __future__ import annotations

import signal
import threading
from concurrent.futures import Future
from concurrent.futures import TimeoutError as Pending
from contextlib import contextmanager
from typing import Any, Callable, Iterator

_pressed = threading.Event()
BACKGROUND = "rosmeery-background-"  # the names of background() threads
_active = threading.Event()  # a deferred block is open (nested blocks share it)


def check() -> None:
    """Raise ``KeyboardInterrupt`` here if Ctrl-C was pressed."""
    if _pressed.is_set():
        _pressed.clear()
        raise KeyboardInterrupt


@contextmanager
def deferred() -> Iterator[None]:
    """Defer Ctrl-C to the next :func:`check` (main thread only; nested blocks defer to
    the outermost)."""
    if threading.current_thread() is not threading.main_thread() or _active.is_set():
        yield
        return
    _pressed.clear()

    def on_sigint(signum, frame):
        _pressed.set()
        signal.signal(signal.SIGINT, previous)  # a second Ctrl-C interrupts at once

    previous = signal.signal(signal.SIGINT, on_sigint)
    _active.set()
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        _active.clear()
        pressed = _pressed.is_set()
        _pressed.clear()
    if pressed:  # pressed after the last check: never lost
        raise KeyboardInterrupt


def background(fn: Callable[[], Any], name: str = "job") -> Future:
    """``fn()`` in a daemon thread (a compile: XLA runs without the GIL). A command that
    stops on Ctrl-C then ends without waiting for it, as it would for an executor's thread."""
    job: Future = Future()

    def run():
        try:
            job.set_result(fn())
        except BaseException as err:  # handed to whoever waits for it
            job.set_exception(err)

    threading.Thread(target=run, name=f"{BACKGROUND}{name}", daemon=True).start()
    return job


def busy() -> bool:
    """Whether a :func:`background` job is still running."""
    return any(t.name.startswith(BACKGROUND) and t.is_alive() for t in threading.enumerate())


def wait(job: Future) -> Any:
    """``job``'s result, Ctrl-C honoured while waiting for it (:func:`check`)."""
    while True:
        try:
            return job.result(timeout=0.2)
        except Pending:
            check()
