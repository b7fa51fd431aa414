"""A session's results folder before anything is written: what ``config.json`` records (the
resolved configuration, the sha256 of every input file, the versions) and the resume guard
(a changed setting or a changed input file is refused rather than mixed in)."""

from __future__ import annotations

import hashlib
import json
import platform
import subprocess
from dataclasses import asdict
from importlib import metadata
from pathlib import Path
from typing import NamedTuple

from rosmeery_jax.core import specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import RECORD, claim_folder, require_same
from rosmeery_jax.detector.detections import weights_file
from rosmeery_jax.policies import LearnedPolicy, policy_class
from rosmeery_jax.policies.learned import policy_file
from rosmeery_jax.policies.teleop_replay import replay_files
from rosmeery_jax.session.config import RESULT_FIELDS, SessionConfig
from rosmeery_jax.session.outputs import INTEGRITY
from rosmeery_jax.world import load_world

VERSIONED = ("rosmeery-jax", "jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy", "pandas", "torch")


def versions() -> dict:
    """The Python and package versions, and the git commit when run from a checkout."""
    out = {"python": platform.python_version()}
    for pkg in VERSIONED:
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass  # not installed (torch without the detector extra)
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).parent,
                             timeout=5)
        out["git"] = rev.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        out["git"] = None
    return out


def _sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def input_hashes(cfg: SessionConfig) -> dict:
    """sha256 of every input file whose contents change results: worlds, recordings, learned
    policies, weights."""
    out = {"worlds": {w.name: _sha256(w.path) for w in map(load_world, cfg.worlds)},
           "recordings": {str(f): _sha256(f) for p in cfg.policies if specs.kind(p) == "replay"
                          for f in replay_files(p)},
           "policies": {p: _sha256(policy_file(p)) for p in cfg.policies
                        if specs.kind(p) != "agent" and policy_class(p) is LearnedPolicy}}
    if cfg.detector == "yolo":
        out["weights"] = _sha256(weights_file(cfg.weights))
    return out


def saved_settings(session: dict) -> dict:
    """A ``config.json``'s session settings, as compared on resume and join: a setting added
    since the folder was written takes its default."""
    return {**json.loads(json.dumps(asdict(SessionConfig()))), **session}


class Claim(NamedTuple):
    """What :func:`check_out` found: the record for config.json, and whether the folder is
    new (nothing of an earlier invocation in it)."""

    record: dict
    fresh: bool


def check_out(cfg: SessionConfig, resume: bool) -> Claim:
    """Check the results folder before anything is written. A resume keeps every setting
    that changes results and every input file; it may add worlds and policies, never drop
    one (config.json would no longer describe the folder's runs)."""
    record = {"session": json.loads(json.dumps(asdict(cfg))), "inputs": input_hashes(cfg), "integrity": INTEGRITY}
    old = claim_folder(cfg.out, resume)
    if old is None:
        return Claim(record, True)
    saved = Path(cfg.out) / RECORD
    if not isinstance(old.get("session"), dict) or not isinstance(old.get("inputs"), dict):
        raise InputError(str(saved), "file", "not a session config: cannot resume from it")
    require_same(saved, saved_settings(old["session"]), record["session"], RESULT_FIELDS)
    for key in ("worlds", "policies"):
        dropped = [x for x in old["session"].get(key) or [] if x not in record["session"][key]]
        if dropped:
            raise InputError(str(saved), key, f"{dropped[0]!r} is in the session: a resume may add {key}, not "
                             "drop them")
    for kind, hashes in record["inputs"].items():
        before = old["inputs"].get(kind, {})
        for name, digest in (hashes.items() if isinstance(hashes, dict) else [(kind, hashes)]):
            was = before.get(name) if isinstance(before, dict) else before
            if was is not None and was != digest:
                raise InputError(str(saved), f"inputs.{kind}", f"{name} has changed since the session started: "
                                 "resume would mix results of two versions")
    record["inputs"] = _merged(old["inputs"], record["inputs"])
    if "joined" in old:  # a folder of joined parts (session.join) keeps saying so
        record["joined"] = old["joined"]
    return Claim(record, False)


def _merged(old: dict, new: dict) -> dict:
    out = dict(old)
    for k, v in new.items():
        out[k] = {**old.get(k, {}), **v} if isinstance(v, dict) else v
    return out
