"""Mutated inputs for every user-facing loader, and the one rule they must keep.

Each loader takes a path; a mutated file must give either a valid result or one
:class:`InputError` whose message is a single line naming the file. Any other exception is
a traceback a user would see: a failure. Shared by ``tests/test_fuzz.py`` (a few hundred
inputs) and ``scripts/fuzz.py`` (thousands, with counts).
"""

from __future__ import annotations

import json
from pathlib import Path

from conftest import room_xml
from hypothesis import strategies as st

CHAIR = '<body name="thing" pos="1 1 0"><geom type="box" pos="0 0 0.2" size="0.2 0.2 0.2"/></body>'
SEED_WORLD = room_xml(CHAIR, {"thing": "chair"}, spawn=(-1.0, -1.0, 0.0))
SEED_CONFIG = ('worlds = ["small_office"]\npolicies = ["random"]\nseeds = 2\nduration = 4.0\n'
               'detector = "off"\nmetrics = ["ori", "opi"]\n[env]\ncamera__cull = 64\n')
SEED_POSES = "t,x,y,yaw\n0,0,0,0\n0.5,0.2,0.1,0.3\n1.0,0.4,0.2,0.6\n"
SEED_TRAJECTORIES = ("world,policy,seed,time_s,x,y,yaw\nroom,random,0,0.0,0,0,0\nroom,random,0,1.0,0.2,0.1,0.3\n"
                     "room,frontier,1,0.0,0,0,0\nroom,frontier,1,1.0,-0.4,0.2,0.6\n")
SEED_MAP_PLY = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                "property int instance\nproperty int label\nproperty float confidence\nend_header\n"
                "0.5 0.5 0.3 0 3 0.9\n0.6 0.5 0.3 0 3 0.8\n-1.0 0.2 0.4 1 -1 0.5\n1.2 -0.4 0.7 2 5 1.0\n")
SEED_MAP_JSON = json.dumps({"frame": {"world": "small_office", "time_s": 12.5},
                            "objects": [{"id": 0, "label": "chair", "confidence": 0.9}, {"id": 1, "label": None},
                                        {"id": 2, "label": "desk", "confidence": 0.4}]})
SEED_TRANSFORM = json.dumps({"transform": [[0, -1, 0, 0.5], [1, 0, 0, -0.2], [0, 0, 1, 0], [0, 0, 0, 1]]})
SEED_PROCEDURAL = "procedural:office:3:rooms=3:objects=12:clutter=0.2"
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
    from rosmeery_jax.policies.teleop_file import world_hash
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
    from rosmeery_jax.policies.teleop_file import check_world
    from rosmeery_jax.policies.teleop_replay import recordings_by_world
    from rosmeery_jax.world import load_world

    for recs in recordings_by_world(f"replay:{path}").values():
        for rec in recs:
            check_world(rec, load_world("small_office"))


def load_poses(path: Path):
    from rosmeery_jax.metrics.trajectory import read_poses

    return read_poses(path)


def load_trajectories(path: Path):
    """One run of a session's trajectories, as ``rosmeery replay --run random:0`` picks it."""
    from rosmeery_jax.metrics.trajectory import read_poses

    return read_poses(path, run=("random", 0))


def load_weights(path: Path):
    from rosmeery_jax.detector import checkpoint

    return checkpoint.load(path)


def load_map_ply(path: Path):
    """A mutated PLY with a valid JSON beside it, read and scored as `rosmeery evaluate` does."""
    path.with_suffix(".json").write_text(SEED_MAP_JSON)
    return _score_map(path)


def load_map_json(path: Path):
    """A valid PLY with a mutated JSON beside it (the file under test)."""
    ply = path.with_suffix(".ply")
    ply.write_text(SEED_MAP_PLY)
    try:
        return _score_map(ply)
    except Exception as err:  # name the JSON in the message check: it is the mutated file
        from rosmeery_jax.core.errors import InputError

        if isinstance(err, InputError) and path.name not in str(err) and ply.name in str(err):
            raise InputError(path, "", str(err)) from None
        raise


def _score_map(ply: Path):
    from rosmeery_jax.metrics import map_score
    from rosmeery_jax.world import load_world

    world = load_world("small_office")
    return map_score.evaluate(world, [map_score.read_map(ply, world.taxonomy)])


def load_transform(path: Path):
    from rosmeery_jax.metrics.align import read_transform

    return read_transform(path)


def load_procedural_name(path: Path):
    """A procedural world's name (the file's text), expanded, parsed and generated."""
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.core.specs import expand_ranges
    from rosmeery_jax.world.generate import generate
    from rosmeery_jax.world.procedural import parse_name

    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(path, "file", "not UTF-8") from None
    try:
        names = list(expand_ranges([text]))
        for name in names[:2]:
            generate(parse_name(name))
    except InputError as err:
        raise InputError(path, "", str(err)) from None
    return names


def policy_bytes() -> bytes:
    from rosmeery_jax.policies.learned import SHIPPED

    return SHIPPED.read_bytes()


def load_policy_file(path: Path):
    from rosmeery_jax.rl.network import load_policy

    return load_policy(path)


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


# --- results folders: what resume, join, plot and diff read -----------------------------

RUN = "small_office__random"
RUN_FILES = {  # a finished run of small_office x random, seeds FIRST..FIRST+1, by hand
    "metrics.csv": "world,policy,detector,mapper,seed,time_s,metric,value\n"
                   + "".join(f"small_office,random,off,oracle,{{s{k}}},{t}.0,ori,0.{t}{k}\n" for k in (0, 1)
                             for t in range(3)),
    "trajectory.csv": "world,policy,seed,time_s,x,y,yaw\n"
                      + "".join(f"small_office,random,{{s{k}}},{t}.0,0.{t},0.{k},0.5\n" for k in (0, 1)
                                for t in range(3)),
    "digest.csv": "seed,chunk,time_s,physics,map,knowledge,detections\n"
                  + "".join(f"{{s{k}}},{c},{c + 1}.0,aa{k}{c},bb{c},cc{c},\n" for k in (0, 1) for c in range(2)),
}


def results_part(folder: Path, first: int = 0) -> Path:
    """A finished session's folder (config.json, run files, their record, the merged table
    and its record), as `rosmeery run` writes them."""
    from rosmeery_jax.results import manifest
    from rosmeery_jax.session.outputs import INTEGRITY, seal_run

    (folder / "runs").mkdir(parents=True)
    (folder / "maps").mkdir()
    session = {"worlds": ["small_office"], "policies": ["random"], "seeds": 2, "first_seed": first, "duration": 2.0,
               "detector": "off", "metrics": ["ori"], "out": str(folder)}
    (folder / "config.json").write_text(json.dumps({"session": session, "inputs": {"worlds": {"small_office": "abc"}},
                                                    "integrity": INTEGRITY}))
    for suffix, text in RUN_FILES.items():
        (folder / "runs" / f"{RUN}.{suffix}").write_text(text.format(s0=first, s1=first + 1))
    seal_run(folder, RUN)
    (folder / "metrics.csv").write_text((folder / "runs" / f"{RUN}.metrics.csv").read_text())
    manifest.write(folder / manifest.MANIFEST, folder, [folder / "metrics.csv"])
    return folder


def _read_results(part: Path, reseal: bool):
    """What --resume, join, plot and diff read of ``part`` (beside a good part of seeds 2-3):
    its records first; with ``reseal`` the damage is recorded as the folder's own, so the
    tables' own checks are what read it."""
    import shutil

    from rosmeery_jax.results import manifest, tables
    from rosmeery_jax.session import digest, join
    from rosmeery_jax.session.outputs import check_folder, seal_run

    base = part.parent / "base"
    if not base.exists():
        results_part(base, first=2)
    if reseal:
        seal_run(part, RUN)
        shutil.copy(part / "runs" / f"{RUN}.metrics.csv", part / "metrics.csv")
        manifest.write(part / manifest.MANIFEST, part, [part / "metrics.csv"])
    check_folder(part)  # resume, plot and diff start here
    tables.load(part)  # what plot reads
    parts = sorted([join._read(part), join._read(base)], key=lambda p: p.seeds.start)
    join._check(parts)
    scratch = part.parent / "joined"
    shutil.rmtree(scratch, ignore_errors=True)
    for name in ("metrics.csv", "trajectory.csv", "digest.csv"):
        join._concat([p.folder / "runs" / f"{RUN}.{name}" for p in parts], scratch / name)
    return digest.compare(base, part)


def results_loader(file: str, reseal: bool):
    """A loader for one file of a results folder: the mutated file is put into a fresh
    finished folder and the folder read as resume, join, plot and diff read it."""
    import shutil

    def load(path: Path):
        from rosmeery_jax.core.errors import InputError

        part = path.parent / "part"
        shutil.rmtree(part, ignore_errors=True)
        results_part(part, first=0)
        target = part / file
        target.write_bytes(path.read_bytes())
        try:
            return _read_results(part, reseal)
        except InputError as err:  # the message names the file it found damaged: the mutated one
            if any(name in str(err) for name in (target.name, "manifest.json", f"{part}/metrics.csv")):  # the
                # merged table is a copy of the run's
                raise InputError(path, "", str(err)) from None
            raise

    load.__name__ = f"load_results_{file.replace('/', '_')}"
    return load


def results_seed(file: str) -> str:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        return (results_part(Path(tmp) / "p") / file).read_text()


# --- plugin modules: a user's metric, policy, mapper and agent in one file ---------------

SEED_PLUGIN = '''
import jax.numpy as jnp
from rosmeery_jax.gym import Agent
from rosmeery_jax.mapping.perceived import PerceivedMapper
from rosmeery_jax.policies.frontier import FrontierPolicy


def seen(log, truth):
    return (log.ps > 0).mean(-1).astype(jnp.float32)


class Explorer(FrontierPolicy):
    name = "explorer"


class Mapper(PerceivedMapper):
    name = "my_mapper"


class Driver(Agent):
    name = "driver"

    def act(self, obs):
        return obs["pose"]
'''
_plugins = {"n": 0}


def load_plugin_module(path: Path):
    """A plugin module's metric, policy, mapper and agent loaded and checked as a session's
    configuration checks them (a fresh file each time: a module is imported once per path)."""
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.gym import agent_class
    from rosmeery_jax.mapping.protocol import mapper_class
    from rosmeery_jax.metrics import indices
    from rosmeery_jax.policies import policy_class

    _plugins["n"] += 1
    fresh = path.with_name(f"{path.stem}_{_plugins['n']}.py")
    fresh.write_bytes(path.read_bytes())
    try:
        policy_class(f"{fresh}:Explorer")
        mapper_class(f"{fresh}:Mapper")
        agent_class(f"agent:{fresh}:Driver")
        indices.resolve([f"{fresh}:seen"])
        indices.REGISTRY.pop("seen", None)  # the next module's metric registers afresh
        indices.CHECKED.pop("seen", None)
        indices.PLUGIN_SPECS.pop("seen", None)
    except InputError as err:
        raise InputError(path, "", str(err).replace(fresh.name, path.name)) from None
    finally:
        fresh.unlink()


# --- ROS 2 bags of maps, both storages: what `rosmeery evaluate --bag` reads ---------------

BAG_TOPIC, BAG_LABELS = "/semantic_map", "/semantic_map/labels"


def bag_seed(storage: str) -> dict[str, bytes]:
    """{file name: bytes} of a valid bag folder (``storage`` mcap or sqlite3) of two map
    clouds on the Small Office's first objects' samples (x, y, z, instance, label,
    confidence) and a labels message, as a ROS mapper's would be recorded."""
    import tempfile

    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from rosmeery_jax.world import load_world

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    truth = load_world("small_office").truth
    pts = np.asarray(truth.samples.points, np.float64)[:60]
    rows = np.zeros(60, [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("instance", "<i4"), ("label", "<i4"),
                         ("confidence", "<f4")])
    rows["x"], rows["y"], rows["z"] = pts.T
    rows["instance"] = np.asarray(truth.samples.object)[:60]
    rows["label"], rows["confidence"] = -1, 0.8
    kinds = {"<f4": 7, "<i4": 5}
    fields = [T["sensor_msgs/msg/PointField"](name=n, offset=rows.dtype.fields[n][1],
                                              datatype=kinds[rows.dtype.fields[n][0].str], count=1)
              for n in rows.dtype.names]

    def cloud(part, t):
        return T["sensor_msgs/msg/PointCloud2"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t, nanosec=0), frame_id="map"),
            height=1, width=len(part), fields=fields, is_bigendian=False, point_step=rows.dtype.itemsize,
            row_step=rows.dtype.itemsize * len(part), data=np.frombuffer(part.tobytes(), np.uint8), is_dense=True)

    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bag"
        plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
        with Writer(bag, version=9, storage_plugin=plugin) as w:
            c = w.add_connection(BAG_TOPIC, "sensor_msgs/msg/PointCloud2", typestore=store)
            s = w.add_connection(BAG_LABELS, "std_msgs/msg/String", typestore=store)
            labels = {"objects": [{"id": 0, "label": str(truth.categories[0]), "confidence": 0.9}]}
            w.write(s, 0, store.serialize_cdr(T["std_msgs/msg/String"](data=json.dumps(labels)), "std_msgs/msg/String"))
            for t, part in ((1, rows[:30]), (2, rows)):
                w.write(c, t * 10**9, store.serialize_cdr(cloud(part, t), "sensor_msgs/msg/PointCloud2"))
        return {p.name: p.read_bytes() for p in bag.iterdir()}


def bag_storage_name(seed: dict[str, bytes]) -> str:
    return next(n for n in seed if n != "metadata.yaml")


def bag_loader(storage: str):
    """A loader for a bag's storage file (.mcap or .db3): the mutated bytes put into a bag
    folder named after the file, its maps read and scored as `rosmeery evaluate --bag` does."""
    import shutil

    seed = bag_seed(storage)

    def load(path: Path):
        from rosmeery_jax.apps.ros_bags import read_maps
        from rosmeery_jax.metrics import map_score
        from rosmeery_jax.world import load_world

        bag = path.parent / f"{path.name}.bag"
        shutil.rmtree(bag, ignore_errors=True)
        bag.mkdir()
        for name, data in seed.items():
            (bag / name).write_bytes(path.read_bytes() if name != "metadata.yaml" else data)
        world = load_world("small_office")
        maps = read_maps(bag, BAG_TOPIC, BAG_LABELS, world.name, world.taxonomy)
        return map_score.evaluate(world, maps)

    load.__name__ = f"load_bag_{storage}"
    return load


# --- Rerun recordings: what `rosmeery view` reads to write one -----------------------------

def rrd_loader(file: str):
    """A loader for one table of a results folder (``metrics.csv`` or ``trajectories.csv``),
    the damage recorded as the folder's own so the tables' own checks read it, then the
    folder written as a Rerun recording (a new .rrd each time)."""
    import shutil

    def load(path: Path):
        from rosmeery_jax.apps import rerun_view
        from rosmeery_jax.core.errors import InputError
        from rosmeery_jax.results import manifest
        from rosmeery_jax.session.outputs import check_folder

        part = path.parent / "viewed"
        shutil.rmtree(part, ignore_errors=True)
        results_part(part, first=0)
        shutil.copy(part / "runs" / f"{RUN}.trajectory.csv", part / "trajectories.csv")
        (part / file).write_bytes(path.read_bytes())
        manifest.write(part / manifest.MANIFEST, part, [part / "metrics.csv", part / "trajectories.csv"])
        rrd = path.parent / "out.rrd"
        rrd.unlink(missing_ok=True)
        try:
            check_folder(part)
            return rerun_view.view(part, rrd)
        except InputError as err:  # it names the table it read: the mutated one
            if file in str(err):
                raise InputError(path, "", str(err)) from None
            raise

    load.__name__ = f"load_rrd_{file.replace('.', '_')}"
    return load


def rrd_seed(file: str) -> str:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        part = results_part(Path(tmp) / "p")
        return (part / ("runs" if file == "trajectories.csv" else "") /
                (f"{RUN}.trajectory.csv" if file == "trajectories.csv" else file)).read_text()
