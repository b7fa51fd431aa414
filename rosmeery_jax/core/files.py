"""Files written so that nothing is ever half-written or silently replaced.

- :func:`atomic_path` / :func:`write_atomic`: a file appears whole or not at all (a temp file
  in the same folder, then a rename), with the process's usual umask mode.
- :func:`claim_folder` / :func:`require_same`: the guard every command that writes a folder
  of results uses: a new or empty folder is taken; a folder that holds another run is
  refused unless resuming, and a resume must keep the settings that change results.
"""

from __future__ import annotations

import fcntl
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from rosmeery_jax.core.errors import InputError

_UMASK = os.umask(0)
os.umask(_UMASK)  # read once: the process's umask, for the mode of files written atomically
RECORD = "config.json"  # the file that marks a folder as one run's and holds its settings
LOCK = ".rosmeery.lock"  # held while a command writes into a folder


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path``: write it inside the ``with``; on success it becomes
    ``path`` in one rename, on any error it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)  # mkstemp makes 0600; results get the usual umask mode
        os.close(fd)
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_atomic(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` so readers never see it half-written."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.encode() if isinstance(data, str) else data)
    return Path(path)


def require_new(out: str | Path, flag: str = "--out", kind: str = "folder") -> Path:
    """An output that must not exist yet, or (a folder) exist and be empty: anything else is
    refused in one line, so nothing the user has is ever replaced."""
    out = Path(out)
    if kind == "file":
        if out.is_dir():
            raise InputError(str(out), flag, "is a folder: name the file to write")
        if out.exists() or out.is_symlink():
            raise InputError(str(out), flag, "exists already: it is never overwritten; choose another name")
        return out
    if out.is_symlink() and not out.exists():
        raise InputError(str(out), flag, "is a broken or looping symbolic link")
    if out.exists() and not out.is_dir():
        raise InputError(str(out), flag, "is a file, not a folder")
    if out.is_dir() and any(out.iterdir()):
        raise InputError(str(out), flag, "is not empty: results are never overwritten; choose another")
    return out


@contextmanager
def output_folder(out: str | Path, flag: str = "--out") -> Iterator[Path]:
    """Create ``out`` (and its parents) for a command's outputs; if the command fails before
    writing anything there, remove what was created, so a refused command leaves nothing."""
    out = Path(out)
    made = [p for p in (out, *out.parents) if not p.exists()]
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(str(out), flag, f"cannot be created ({err.strerror or err})") from None
    try:
        yield out
    except BaseException:
        for p in made:  # deepest first; only folders this call made and that are still empty
            try:
                p.rmdir()
            except OSError:
                break
        raise


def claim_folder(out: str | Path, resume: bool, holds: str = "results") -> dict | None:
    """Check the output folder ``out`` before anything is written. Returns None for a new or
    empty folder, or the saved record (its ``config.json``) of a folder being resumed;
    refuses a file, a folder holding something else, or results without ``resume``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "out", "is a file, not a results folder")
    saved = out / RECORD
    if not saved.exists():
        if out.exists() and any(p.name != LOCK for p in out.iterdir()):
            raise InputError(str(out), "out", f"is not empty and has no {RECORD}: choose another --out")
        return None
    if not resume:
        raise InputError(str(out), "out", f"already holds {holds}: pass --resume to continue, or choose another --out")
    try:
        old = json.loads(saved.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        old = None
    if not isinstance(old, dict):
        raise InputError(str(saved), "file", "unreadable or not a run's config: cannot resume from it")
    return old


@contextmanager
def folder_lock(out: str | Path) -> Iterator[None]:
    """Hold ``out``'s lock while writing into it: a second command on the same folder (two
    ``--resume`` at once) is refused instead of doing the same work beside the first."""
    path = Path(out) / LOCK
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666 & ~_UMASK)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise InputError(str(out), "out", "is in use by another rosmeery command: wait for it, or choose another "
                         "--out") from None
    try:
        yield
    finally:
        path.unlink(missing_ok=True)  # under the lock: the next command makes its own
        os.close(fd)


def require_same(saved: str | Path, old: dict, new: dict, keys, what: str = "resume") -> None:
    """A resume (or ``what`` else) keeps every setting named in ``keys``: one InputError
    naming the first that changed."""
    for key in keys:
        if old.get(key) != new.get(key):
            raise InputError(str(saved), key, f"was {old.get(key)!r}, now {new.get(key)!r}: {what} needs the "
                             "same setting")
