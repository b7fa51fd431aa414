"""Mutated inputs for every user-facing loader, and the one rule they must keep.

Each loader takes a path; a mutated file must give either a valid result or one
:class:`InputError` whose message is a single line naming the file. Any other exception is
a traceback a user would see: a failure. Shared by ``tests/test_fuzz.py`` (a few hundred
inputs) and ``scripts/fuzz.py`` (thousands, with counts).
"""

from __future__ import annotations

import json
from pathlib import Path

from hypothesis import strategies as st

from conftest import room_xml

CHAIR = '<body name="thing" pos="1 1 0"><geom type="box" pos="0 0 0.2" size="0.2 0.2 0.2"/></body>'
SEED_WORLD = room_xml(CHAIR, {"thing": "chair"}, spawn=(-1.0, -1.0, 0.0))
SEED_CONFIG = ('worlds = ["small_office"]\npolicies = ["random"]\nseeds = 2\nduration = 4.0\n'
               'detector = "off"\nmetrics = ["ori", "opi"]\n[env]\ncamera__cull = 64\n')
SEED_POSES = "t,x,y,yaw\n0,0,0,0\n0.5,0.2,0.1,0.3\n1.0,0.4,0.2,0.6\n"
# Tokens a mutation splices in: numbers at the edges, wrong types, broken syntax.
TOKENS = ["nan", "inf", "-inf", "1e30", "-1e30", "1e308", "0", "-1", "1.5", '"x"', "true", "[]", "{}", "[", "]",
          "<", ">", "/>", '"', "=", ",", "\n", "\x00", "\xe9", "null", "NaN", "Infinity", "-0", "1e-30", "9" * 30]


def mutate(text: str, edits: list[tuple[int, int, str]]) -> str:
    """Apply (position, delete count, insert) edits to text, positions taken modulo length."""
    for pos, delete, insert in edits:
        p = pos % (len(text) + 1)
        text = text[:p] + insert + text[p + delete:]
    return text


def edits(max_edits: int = 4):
    return st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 8),
                              st.one_of(st.sampled_from(TOKENS), st.text(max_size=6))), min_size=1,
                    max_size=max_edits)


def number_swaps(text: str):
    """Strategy: the text with some of its numbers replaced by edge values."""
    import re

    spans = [m.span() for m in re.finditer(r"-?\d+(\.\d+)?(e-?\d+)?", text)]

    @st.composite
    def swap(draw):
        out, last, parts = [], 0, draw(st.lists(st.integers(0, max(0, len(spans) - 1)), max_size=3))
        chosen = set(parts)
        for i, (a, b) in enumerate(spans):
            out.append(text[last:a])
            out.append(draw(st.sampled_from(TOKENS[:16])) if i in chosen else text[a:b])
            last = b
        out.append(text[last:])
        return "".join(out)

    return swap()


def recording_text() -> str:
    from rosmeery_jax.policies.recording import world_hash
    from rosmeery_jax.world import load_world

    w = load_world("small_office")
    head = {"format": "rosmeery-teleop", "version": 1, "world": "small_office", "world_sha256": world_hash(w),
            "seed": 0, "dt": 0.1, "start_pose": [float(v) for v in w.spawn], "env": {}, "detector": "off"}
    steps = [{"k": k, "t": k / 10, "cmd": [0.5, 0.1], "pose": [0.0, 0.0, 0.0]} for k in range(1, 6)]
    return "\n".join(json.dumps(x) for x in [head, *steps, {"end": True, "steps": 5}]) + "\n"


# --- the loaders under test: path -> anything; InputError is the only allowed failure ---

def load_world_file(path: Path):
    from rosmeery_jax.world import load_world

    return load_world(path)


def load_session_config(path: Path):
    from rosmeery_jax.session import load_config

    return load_config(path, out=str(path.parent / "never_written"))


def load_recording(path: Path):
    from rosmeery_jax.policies.replay import recordings_by_world
    from rosmeery_jax.policies.recording import check_world
    from rosmeery_jax.world import load_world

    for recs in recordings_by_world(f"replay:{path}").values():
        for rec in recs:
            check_world(rec, load_world("small_office"))


def load_poses(path: Path):
    from rosmeery_jax.scoring.pose_replay import read_poses

    return read_poses(path)


def load_weights(path: Path):
    from rosmeery_jax.detector import checkpoint

    return checkpoint.load(path)


def check_one(loader, path: Path) -> str:
    """'ok', 'error' (a one-line InputError naming the file), or raises AssertionError with
    the offending exception for anything else."""
    from rosmeery_jax.core.errors import InputError

    try:
        loader(path)
    except InputError as err:
        msg = str(err)
        assert "\n" not in msg and path.name in msg, f"error does not name the file in one line: {msg!r}"
        return "error"
    except Exception as err:  # noqa: BLE001 - this is what the fuzzing looks for
        raise AssertionError(f"{loader.__name__}: traceback-worthy {type(err).__name__}: {err}") from err
    return "ok"
