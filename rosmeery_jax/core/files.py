"""Files written so that nothing is ever half-written or silently replaced.

- :func:`atomic_path` / :func:`write_atomic`: a file appears whole or not at all (a temp file
  in the same folder, then a rename), with the process's usual umask mode.
- :func:`claim_folder` / :func:`require_same`: the guard every command that writes a folder
  of results uses: a new or empty folder is taken; a folder that holds another run is
  refused unless resuming, and a resume must keep the settings that change results.
"""

from __future__ import annotations

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


def claim_folder(out: str | Path, resume: bool, holds: str = "results") -> dict | None:
    """Check the output folder ``out`` before anything is written. Returns None for a new or
    empty folder, or the saved record (its ``config.json``) of a folder being resumed;
    refuses a file, a folder holding something else, or results without ``resume``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "out", "is a file, not a results folder")
    saved = out / RECORD
    if not saved.exists():
        if out.exists() and any(out.iterdir()):
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


def require_same(saved: str | Path, old: dict, new: dict, keys) -> None:
    """A resume keeps every setting named in ``keys``: one InputError naming the first that
    changed."""
    for key in keys:
        if old.get(key) != new.get(key):
            raise InputError(str(saved), key, f"was {old.get(key)!r}, now {new.get(key)!r}: resume needs the "
                             "same setting")
