"""A sweep split over results folders, joined into one: ``rosmeery join A B --out C``.

Each part is a finished session of the same settings over its own seeds
(``--first-seed``). Every seed's numbers are the same whatever the other seeds of its
session, so the joined folder holds the files one session of all the seeds would have
written: each run's files are the parts' files in seed order (their text, unparsed), the
maps are copied, and the merged tables and plots are drawn again. Its ``config.json`` is
that session's, so ``--resume``, ``plot``, ``diff`` and the table scripts read it as one;
``joined`` in it lists each part's folder, seeds and versions. Times are the parts' summed.

Nothing is written until every part is checked: one line names the first file and field
that keeps them apart. The folder is built beside ``--out`` and moved there at the end,
so an interrupted join leaves nothing half-written.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import NamedTuple

from rosmeery_jax.core import specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import RECORD, output_folder, require_new, require_same, write_atomic
from rosmeery_jax.results import manifest
from rosmeery_jax.session.config import RESULT_FIELDS
from rosmeery_jax.session.folder import saved_settings
from rosmeery_jax.session.outputs import finished, merge, rates, run_damage, seal_run

SPLIT = ("seeds", "first_seed", "out")  # the settings the parts may differ in (and their versions)
RATES = ("env_steps_per_s", "sim_env_steps_per_s")  # in timing files: from the sums, not summed


class SweepPart(NamedTuple):
    """One part: its folder, its ``config.json`` record and its seeds."""

    folder: Path
    record: dict
    seeds: range


def join(folders: list[str | Path], out: str | Path) -> Path:
    """Join the finished sessions in ``folders`` into the new folder ``out``."""
    if isinstance(folders, (str, Path)):  # its letters would be read as folders
        raise TypeError(f"join_results: a list of results folders, not one ({folders!r})")
    parts = sorted((_read(Path(f)) for f in folders), key=lambda p: p.seeds.start)
    _check(parts)
    out = require_new(out)
    with output_folder(out):
        scratch = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
        os.chmod(scratch, out.stat().st_mode & 0o777)  # the mode mkdir gave --out (mkdtemp's is 0700)
        try:
            _write(parts, scratch, out)
            scratch.replace(out)  # an empty folder is replaced whole
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
    return out


def _read(folder: Path) -> SweepPart:
    """A part's record and seeds; refused unless it is a session whose every run finished."""
    saved = folder / RECORD
    try:
        record = json.loads(saved.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(str(saved), "file", "not found: not a results folder") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(str(saved), "file", f"unreadable ({err})") from None
    session = record.get("session") if isinstance(record, dict) else None
    if not isinstance(session, dict) or not isinstance(record.get("inputs"), dict):
        raise InputError(str(saved), "file", "not a session's config")
    first, count = session.get("first_seed", 0), session.get("seeds")
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (first, count)) or first < 0 or count < 1 \
            or first + count - 1 > specs.MAX_SEED:
        raise InputError(str(saved), "seeds", f"first_seed {first!r}, seeds {count!r}: not a range of seeds (0 to "
                         f"{specs.MAX_SEED})")
    names = {}
    for key in ("worlds", "policies"):
        names[key] = session.get(key)
        if not isinstance(names[key], list) or not names[key] or not all(isinstance(x, str) for x in names[key]):
            raise InputError(str(saved), key, f"{names[key]!r}: not a list of names")
    for policy in names["policies"]:
        if specs.kind(policy) == "replay":
            raise InputError(str(saved), "policies", f"{policy!r}: a replay's runs are its recordings, not seeds, "
                             "so its parts cannot be joined")
    done = finished(folder)
    runs = len(names["worlds"]) * len(names["policies"])
    if len(done) < runs:  # a run's record of its files is written last: it marks the run done
        raise InputError(str(folder / "runs"), "runs", f"{len(done)} of the session's {runs} runs finished: resume "
                         "it first")
    for name in done:
        err = run_damage(folder, name)
        if err is not None:
            raise InputError(err.source, err.where, f"{err.problem}: resume {folder} to simulate the run again")
    return SweepPart(folder, record, range(first, first + count))


def _check(parts: list[SweepPart]) -> None:
    """The parts share every setting but their seeds, and their seeds follow each other."""
    if len(parts) < 2:
        raise InputError("join", "folders", "give two results folders or more")
    first = parts[0]
    keys = [k for k in ("worlds", "policies", *RESULT_FIELDS) if k not in SPLIT]
    for part in parts[1:]:
        saved = part.folder / RECORD
        require_same(saved, saved_settings(first.record["session"]), saved_settings(part.record["session"]), keys,
                     "a join")
        if part.record["inputs"] != first.record["inputs"]:
            raise InputError(str(saved), "inputs", f"its input files differ from {first.folder / RECORD}'s: "
                             "the parts ran on other worlds, recordings, policies or weights")
        mine, theirs = (finished(x.folder) for x in (part, first))
        if mine != theirs:
            odd = sorted(set(mine) ^ set(theirs))[0]
            raise InputError(str(part.folder / "runs"), "runs", f"{odd} is in one part only")
    for before, part in zip(parts, parts[1:]):
        if part.seeds.start < before.seeds.stop:
            raise InputError(str(part.folder / RECORD), "first_seed", f"seeds {_span(part.seeds)} overlap "
                             f"{before.folder}'s {_span(before.seeds)}")
        if part.seeds.start > before.seeds.stop:
            raise InputError(str(part.folder / RECORD), "first_seed", f"seeds {_span(part.seeds)} leave seeds "
                             f"{_span(range(before.seeds.stop, part.seeds.start))} out after {before.folder}'s "
                             f"{_span(before.seeds)}: the joined folder would be no one session's")


def _span(seeds: range) -> str:
    return f"{seeds.start}-{seeds.stop - 1}" if len(seeds) > 1 else str(seeds.start)


def _write(parts: list[SweepPart], scratch: Path, out: Path) -> None:
    """Every file of the joined folder into ``scratch`` (which becomes ``out``)."""
    for name in sorted({p.name for part in parts for p in (part.folder / "runs").glob("*.csv")}):
        _concat([part.folder / "runs" / name for part in parts], scratch / "runs" / name)
    for name in sorted({p.name for part in parts for p in (part.folder / "runs").glob("*.timing.json")}):
        _sum_timing([part.folder / "runs" / name for part in parts], scratch / "runs" / name)
    (scratch / "maps").mkdir()
    for part in parts:
        for path in sorted((part.folder / "maps").glob("*")) if (part.folder / "maps").is_dir() else []:
            if path.is_file():
                shutil.copy2(path, scratch / "maps" / path.name)
    for name in finished(parts[0].folder):
        seal_run(scratch, name)
    merge(scratch)
    _sum_timing([part.folder / "timing.json" for part in parts], scratch / "timing.json")
    seeds = range(parts[0].seeds.start, parts[-1].seeds.stop)
    record = {**parts[0].record, "session": {**parts[0].record["session"], "first_seed": seeds.start,
                                             "seeds": len(seeds), "out": str(out)},
              "joined": [entry for p in parts for entry in _provenance(p)]}
    write_atomic(scratch / RECORD, json.dumps(record, indent=2))


def _provenance(part: SweepPart) -> list[dict]:
    """What ``joined`` lists of a part: its folder, seeds and versions; a part that was joined
    itself, its own parts."""
    if isinstance(part.record.get("joined"), list):
        return part.record["joined"]
    return [{"folder": str(part.folder), "first_seed": part.seeds.start, "seeds": len(part.seeds),
             "versions": part.record.get("versions")}]


def _concat(paths: list[Path], dest: Path) -> None:
    """The CSV files' rows one after another (each part's rows are in seed order), one header;
    a file that one part has, every part has."""
    missing = [p for p in paths if not p.exists()]
    if missing:
        other = next(p for p in paths if p.exists())
        raise InputError(str(missing[0]), "file", f"not found, where {other} is: the parts wrote other files")
    texts = [p.read_text(encoding="utf-8") for p in paths]
    header = texts[0].split("\n", 1)[0]
    rows = []
    for path, text in zip(paths, texts):
        head, _, body = text.partition("\n")
        if head != header:
            raise InputError(str(path), "columns", f"{head!r} where {paths[0]} has {header!r}")
        rows.append(body)
    write_atomic(dest, header + "\n" + "".join(rows))


def _sum_timing(paths: list[Path], dest: Path) -> None:
    """The parts' times and counts summed, rates from the sums, their groups listed: what the
    runs cost in all (on the parts' machines), in the keys a session's timing file has."""
    found = [json.loads(p.read_text(encoding="utf-8")) for p in paths if p.exists()]
    if not found:
        return
    number = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)  # noqa: E731
    total = {k: sum(t[k] for t in found) for k in found[0]
             if k not in RATES and k != "devices" and all(number(t.get(k)) for t in found)}
    if {"env_steps", "wall_s", "sim_s"} <= set(total):
        total.update(rates(total["env_steps"], total["wall_s"], total["sim_s"]))
    if any("groups" in t for t in found):
        total["groups"] = [g for t in found for g in t.get("groups", [])]
    write_atomic(dest, json.dumps({**total, "note": f"the times of {len(found)} joined parts, summed"}, indent=2))
