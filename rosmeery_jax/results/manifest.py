"""A results folder's record of its own files, so that damage is found before a folder is
resumed, joined, plotted or compared, not taken for a result.

Each file is listed, once complete, with its size, its sha256 and, for a CSV file, its rows
and a digest of every block of ``BLOCK`` rows (so a changed row is named to within its
block). A session writes one manifest per run (``runs/<run>.manifest.json``, last: its
presence marks the run done) and one for the merged tables (``manifest.json``).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import write_atomic

MANIFEST = "manifest.json"
RUN_SUFFIX = ".manifest.json"
BLOCK = 1024  # CSV rows per block digest


def describe(path: Path) -> dict:
    """A file's entry: bytes, sha256 and, for a CSV file, rows and block digests."""
    data = path.read_bytes()
    entry = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    if path.suffix == ".csv":
        rows = data.split(b"\n")[1:]
        rows = rows[:-1] if rows and rows[-1] == b"" else rows
        entry["rows"] = len(rows)
        entry["blocks"] = [hashlib.sha256(b"\n".join(rows[i:i + BLOCK])).hexdigest()[:16]
                           for i in range(0, len(rows), BLOCK)]
    return entry


def write(manifest: Path, root: Path, files: list[Path]) -> Path:
    """Record ``files`` (under ``root``) in ``manifest``, atomically."""
    listed = {p.relative_to(root).as_posix(): describe(p) for p in sorted(files)}
    return write_atomic(manifest, json.dumps({"files": listed}, indent=1))


def damage(manifest: Path, root: Path, expected: list[Path] = ()) -> InputError | None:
    """The first damage to the files ``manifest`` lists (a missing, changed or unreadable
    file, or the manifest itself, or one that lists fewer files than ``expected``: what the
    run wrote), as an InputError naming the file and row; None if none."""
    try:
        files = json.loads(manifest.read_text(encoding="utf-8"))["files"]
        items = list(files.items())
        if not all(isinstance(k, str) and isinstance(v, dict) for k, v in items):
            raise ValueError
    except FileNotFoundError:
        return InputError(str(manifest), "file", "not found: no record of the files written")
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError):
        return InputError(str(manifest), "file", "unreadable: the record of the files written is damaged")
    unlisted = sorted({p.relative_to(root).as_posix() for p in expected} - set(files))
    if unlisted:
        return InputError(str(manifest), "files", f"does not list {unlisted[0]} ({len(unlisted)} of the files written "
                          "not listed): the record of the files written is damaged")
    for rel, want in items:
        path = root / rel
        if not path.is_file():
            return InputError(str(path), "file", "not found, where the results folder recorded it")
        have = describe(path)
        if have.get("sha256") != want.get("sha256"):
            return InputError(str(path), *_where(have, want))
    return None


def _where(have: dict, want: dict) -> tuple[str, str]:
    """Where a changed file differs, and how: its row count, or the first block of rows (as
    line numbers) that differs."""
    if "rows" not in have or not isinstance(want.get("blocks"), list):
        return "file", "differs from what was written"
    if have["rows"] != want.get("rows"):
        return "rows", f"{have['rows']} where {want.get('rows')} were written"
    block = next((i for i, (a, b) in enumerate(zip(have["blocks"], want["blocks"])) if a != b), 0)
    first = block * BLOCK + 2  # line numbers: the header is line 1
    return f"lines {first}-{min(first + BLOCK - 1, have['rows'] + 1)}", "differ from what was written"


def check(manifest: Path, root: Path) -> None:
    """Raise the first damage :func:`damage` finds."""
    err = damage(manifest, root)
    if err is not None:
        raise err
