"""Executed object-goal tasks (``task = "objectnav"``, docs/tasks.md): after exploring, each
robot drives its world's episodes in the simulation, once per mapper, with that mapper's
final map.

Per episode the map gives the plan (:meth:`rosmeery_jax.metrics.tasks.TaskScorer.route`):
the instances labelled with the goal to try, nearest first, each with the approach pose
the query would stop at (facing the instance's centre). The robot is put at the start
(its estimate there too) and its navigator drives to the first goal pose on the robot's
own occupancy map, localising as it explored (noise and localisation apply). When the
navigator is done with a goal (reached it or gave up), the robot checks the stop as the
query does: a true object of the goal category within 1.0 m with a line of sight, i.e.
its true pose in the category's success region. If so, or if no instance is left to try,
the episode ends there; else it drives on to the next goal.

The drives run in the compiled program of :func:`rosmeery_jax.session.program.drive_fn`:
``SLOTS`` drives per robot at once, ``STEPS`` control steps per call; between calls the
host checks the drives that ended and gives them their next goal or their next episode.

Shapes: B envs of the group, S slots per env, E episodes, A attempts, M mappers.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from scipy import ndimage

from rosmeery_jax.core import plugins
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import drive
from rosmeery_jax.mapping.protocol import MapState, mapper_label
from rosmeery_jax.metrics.map_file import knowledge_points
from rosmeery_jax.policies.base import Policy
from rosmeery_jax.session.batch import Group
from rosmeery_jax.session.program import drive_fn
from rosmeery_jax.sim.navigation import IDLE, STATUS_NAMES
from rosmeery_jax.world import episodes as episodes_

SLOTS = 16  # drives per robot at once, at most (fewer where no robot has as many episodes to drive)
STEPS = 50  # control steps per call of the drive program (5 s)
INWARD = 0.3  # m: a goal pose's least depth inside its instance's approach region (twice the goal tolerance)
STREAM = 0x7A5C  # the drives' keys: folded into the seed's key, then the episode's copy index

COLUMNS = ("world", "policy", "mapper", "seed", "episode", "goal", "start_x", "start_y", "start_yaw", "instance",
           "attempts", "stop_x", "stop_y", "stop_yaw", "navigator", "success", "spl", "softspl", "distance_m", "path_m",
           "shortest_m", "time_s", "query_success")


class Copy(NamedTuple):
    """One episode of one robot and map: its env row, mapper (its results' label) and episode; the goal
    poses to try (k, 3), k <= attempts, and their instance ids (k,) (-1: a policy's own
    goal), and the query's verdict (None: no query, an agent's own search)."""

    row: int
    mapper: str
    episode: episodes_.Episode
    goals: np.ndarray
    instance: np.ndarray
    query_success: bool | None

    @property
    def tries(self) -> int:
        return len(self.goals)


class Ended(NamedTuple):
    """An episode driven: the attempts it made, its true stop pose (3,), path (m), steps,
    whether it stopped in a success region, and how the navigator ended its last drive
    (``sim.navigation``'s status code; an agent's episode: "stopped" or "timeout")."""

    copy: Copy
    attempts: int
    stop: np.ndarray
    path: float
    steps: int
    success: bool = False
    status: int | str = IDLE


def plan(world, scorer, m: MapState, row: int, mapper: str, policy=None, spec: str = "") -> list[Copy]:
    """The episodes of ``scorer`` (a TaskScorer of ``world``) for the final map ``m`` of
    env ``row``'s mapper entry ``mapper``: the built-in search's goals, or those of
    ``policy``'s ``task_goals`` (the plugin entry ``spec``) where it gives some."""
    names = world.taxonomy.names
    labels = {i: names[c] for i, c in enumerate(np.asarray(m.label).tolist()) if c >= 0}
    points, instance = np.asarray(m.points, np.float64).reshape(-1, 3), np.asarray(m.instance, np.int64)
    query = scorer.score(points, instance, labels)
    picks, cells = scorer.route(points, instance, labels)
    goals = np.zeros((*picks.shape, 3), np.float32)
    depth = {}  # instance id -> (H, W) metres inside its approach region
    for e, a in zip(*np.nonzero(picks >= 0)):
        i = int(picks[e, a])
        mine = points[instance == i, :2]
        if i not in depth:
            region = episodes_.approach_region(world, mine)
            depth[i] = ndimage.distance_transform_edt(region) * world.free_space.resolution
        goals[e, a] = goal_pose(world.free_space, cells[e, a], depth[i], mine)
    out = []
    for e, ep in enumerate(scorer.episodes):
        own = own_goals(policy, spec, m, ep.start, ep.goal, scorer.attempts) if policy is not None else None
        tried = picks[e] >= 0
        out.append(Copy(row, mapper, ep, goals[e][tried], picks[e][tried], bool(query.success[e])) if own is None
                   else Copy(row, mapper, ep, own, np.full(len(own), -1), bool(query.success[e])))
    return out


def own_goals(policy, spec: str, m: MapState, start, goal: str, attempts: int) -> np.ndarray | None:
    """A policy plugin's (entry ``spec``) goals as (k, 3) float32, None for the built-in
    search, or one InputError naming the plugin."""
    with plugins.raised_by(spec, "policies", "task_goals"):
        own = policy.task_goals(m, np.asarray(start, np.float32), goal, attempts)
    if own is None:
        return None
    try:
        own = np.asarray(own, np.float32).reshape(-1, 3)
    except (TypeError, ValueError):
        own = None
    if own is None or len(own) > attempts or not np.isfinite(own).all():
        raise InputError("config", "policies", f"plugin {spec!r}: task_goals must return at most {attempts} finite "
                         "poses (x, y, yaw) or None")
    return own


def goal_pose(fs, node: np.ndarray, depth: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(3,) the pose to drive to for an instance of ``points`` (P, 2) whose query stops at
    cell ``node`` (2,) (row, col), ``depth`` (H, W) metres inside its approach region: the
    free cell nearest the node at least ``INWARD`` inside (or the deepest there is), so the
    navigator's goal tolerance cannot leave the robot outside (the node nearest the start
    lies on the region's edge), facing the instance's nearest point."""
    free = fs.reachable & (depth > 0)
    inside = free & (depth >= min(INWARD, depth[free].max(initial=0.0)))
    cells = np.argwhere(inside) if inside.any() else node[None]
    cell = cells[np.argmin(np.hypot(*(cells - node).T))]
    xy = fs.origin + (cell[::-1] + 0.5) * fs.resolution
    way = points[np.argmin(np.hypot(*(points - xy).T))] - xy
    return np.array([*xy, np.arctan2(way[1], way[0])], np.float32)


class Judge:
    """The success regions and distance fields of a world's goals, read at true poses."""

    def __init__(self, world):
        self.fs, self.reg = world.free_space, episodes_.regions(world)
        # a pose off the free-space graph (the robot's centre grazing an obstacle's margin)
        # is read at the nearest reachable cell
        self.near = ndimage.distance_transform_edt(~self.fs.reachable, return_distances=False, return_indices=True)

    def cell(self, xy) -> tuple[int, int]:
        h, w = self.fs.reachable.shape
        i, j = self.fs.cell(xy)
        i, j = min(max(i, 0), h - 1), min(max(j, 0), w - 1)
        return int(self.near[0, i, j]), int(self.near[1, i, j])

    def success(self, goal: str, xy) -> bool:
        return bool(self.reg.region[goal][self.cell(xy)])

    def distance(self, goal: str, xy) -> float:
        return float(self.reg.distance[goal][self.cell(xy)])


class Slots:
    """Which copy each of a robot's S drives holds (B, S; -1: none left) and its attempt,
    with the program's inputs for the next call: goals, starts and ``again`` (start
    afresh). Each robot's copies wait in its queue; S is ``SLOTS`` or, where no robot has
    that many copies to drive, the most any robot has (the program computes every slot)."""

    def __init__(self, copies: list[Copy], b: int):
        self.copies = copies
        self.queue = [[k for k, c in enumerate(copies) if c.row == r and c.tries] for r in range(b)]
        s = max(1, min(SLOTS, max(map(len, self.queue))))
        self.copy, self.attempt = np.full((b, s), -1), np.zeros((b, s), np.int64)
        self.goals, self.starts = np.zeros((b, s, 3), np.float32), np.zeros((b, s, 3), np.float32)
        self.again = np.zeros((b, s), bool)
        for r in range(b):
            for k in range(s):
                self.fill(r, k)

    def fill(self, r: int, k: int) -> None:
        """Slot (r, k) takes its robot's next copy, if any, from its start."""
        self.copy[r, k] = self.queue[r].pop(0) if self.queue[r] else -1
        self.attempt[r, k] = 0
        if self.copy[r, k] >= 0:
            c = self.copies[self.copy[r, k]]
            self.goals[r, k], self.starts[r, k], self.again[r, k] = c.goals[0], c.episode.start, True

    def next_goal(self, r: int, k: int) -> None:
        self.attempt[r, k] += 1
        self.goals[r, k] = self.copies[self.copy[r, k]].goals[self.attempt[r, k]]


def run(group: Group, logodds: jax.Array, copies: list[Copy], judges: dict) -> list[Ended]:
    """Drive every copy (their ``row`` indexes the group's B envs; ``logodds`` (B, H, W) the
    robots' maps at the end of exploring; ``judges`` a Judge per world index); the
    episodes as they ended, in no set order."""
    fn = drive_fn(group, STEPS, STREAM)
    blocks = jnp.asarray(group.blocks)
    ended = [Ended(c, 0, np.asarray(c.episode.start, np.float32), 0.0, 0) for c in copies if not c.tries]
    slots = Slots(copies, group.size)
    s = slots.copy.shape[1]
    drives = _empty(group, logodds, group.size, s)
    seeds = np.repeat(np.asarray(group.seed, np.uint32)[:, None], s, 1)
    while (slots.copy >= 0).any():
        drives = fn(group.data, blocks, logodds, drives, *map(jnp.asarray, (
            slots.goals, slots.again, slots.starts, seeds, np.maximum(slots.copy, 0).astype(np.uint32))))
        slots.again[:] = False
        done, stop, path, steps, status = jax.device_get(  # one copy to the host per call
            (drives.ended, drives.stop, drives.path, drives.steps, drives.state.nav.status))
        for r, k in zip(*np.nonzero(done & (slots.copy >= 0))):
            c, tried = copies[slots.copy[r, k]], slots.attempt[r, k] + 1
            success = judges[int(group.world[r])].success(c.episode.goal, stop[r, k, :2])
            if success or tried >= c.tries:
                ended.append(Ended(c, tried, stop[r, k], float(path[r, k]), int(steps[r, k]), success,
                                   int(status[r, k])))
                slots.fill(r, k)
            else:
                slots.next_goal(r, k)
    return ended


def _empty(group: Group, logodds: jax.Array, b: int, s: int):
    """(B, S) drives of zeros in the shape the program keeps (each starts afresh first)."""
    shape = jax.eval_shape(lambda: drive.start(group.env, jnp.zeros(3), logodds[0], jax.random.key(0)))

    def zeros(leaf):
        if jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            return jax.random.wrap_key_data(jnp.zeros((b, s, *leaf.shape, 2), jnp.uint32))
        return jnp.zeros((b, s, *leaf.shape), leaf.dtype)

    return jax.tree.map(zeros, shape)


def for_group(group: Group, query, sim, mappers: tuple[str, ...], policy_names: list[str]) -> dict[str, pd.DataFrame]:
    """Every real env of ``group`` drives ``query``'s episodes (a TaskQuery: its count and
    attempts) once per entry of ``mappers`` (an engine Simulation ``sim`` whose ``logodds``
    holds the robots' maps); tasks.csv's rows per run name."""
    real = np.flatnonzero(group.real)
    scorers = {w: query.scorer(group.envs[w].world) for w in sorted(set(group.world[real].tolist()))}
    owner = {int(row): r for r in group.runs for row in r.rows}
    copies = []
    for j, row in enumerate(real.tolist()):
        w = int(group.world[row])
        world = group.envs[w].world
        run_of = owner[row]
        own = run_of.host_policy if type(run_of.host_policy).task_goals is not Policy.task_goals else None
        for spec, m in final_maps(world, sim, j, mappers).items():
            copies += plan(world, scorers[w], m, row, mapper_label(spec), own, run_of.spec)
    judges = {w: Judge(group.envs[w].world) for w in scorers}
    ended = run(group, sim.logodds, copies, judges)
    out = {}
    for r in group.runs:
        rows = set(r.rows.tolist())
        mine = [e for e in ended if e.copy.row in rows]
        seed = dict(zip(r.rows.tolist(), r.seeds))
        out[r.name] = frame(mine, judges[r.world], group.envs[r.world].world.name, policy_names[r.policy], seed,
                            group.env.dt)
    return out


def final_maps(world, sim, j: int, mappers: tuple[str, ...]) -> dict[str, MapState]:
    """Real env ``j``'s final map per entry of ``mappers``: the built-in knowledge's (its
    observed samples, ``oracle``) and each fed mapper's last scored map."""
    out = {}
    if "oracle" in mappers:
        k, n = sim.knowledge, world.truth.num_objects
        points, instance = knowledge_points(world, k.seen[j][:len(world.truth.samples.object)])
        out["oracle"] = MapState(points, instance, np.asarray(k.label[j][:n]),
                                 np.asarray(k.confidence[j][:n], np.float32))
    return {**out, **{spec: per_env[j].final for spec, per_env in (sim.mapped or {}).items()}}


def frame(ended: list[Ended], judge: Judge, world: str, policy: str, seed: dict, dt: float) -> pd.DataFrame:
    """tasks.csv's rows (COLUMNS) of one run's ``ended`` episodes; ``seed`` per env row."""
    rows = []
    for e in ended:
        c, ep = e.copy, e.copy.episode
        success = e.success
        d = judge.distance(ep.goal, e.stop[:2]) if e.attempts else ep.geodesic_distance
        shortest = ep.geodesic_distance
        efficiency = shortest / max(e.path, shortest, 1e-12)
        rows.append({"world": world, "policy": policy, "mapper": c.mapper, "seed": seed[c.row],
                     "episode": ep.id, "goal": ep.goal, "start_x": ep.start[0], "start_y": ep.start[1],
                     "start_yaw": ep.start[2], "instance": int(c.instance[e.attempts - 1]) if e.attempts else -1,
                     "attempts": e.attempts, "stop_x": float(e.stop[0]), "stop_y": float(e.stop[1]),
                     "stop_yaw": float(e.stop[2]),
                     "navigator": e.status if isinstance(e.status, str) else STATUS_NAMES[e.status],
                     "success": int(success),
                     "spl": float(success * efficiency),
                     "softspl": float(np.clip(1 - d / max(shortest, 1e-12), 0, 1) * efficiency),
                     "distance_m": d, "path_m": e.path, "shortest_m": shortest, "time_s": round(e.steps * dt, 6),
                     "query_success": -1 if c.query_success is None else int(c.query_success)})
    df = pd.DataFrame(rows, columns=list(COLUMNS))
    return df.sort_values(["world", "policy", "seed", "mapper", "episode"]).reset_index(drop=True)  # seed-major,
    # as every run file: `rosmeery join` concatenates the parts' seeds


def means(tasks: pd.DataFrame) -> pd.DataFrame:
    """The four executed-task metrics per run, mapper and seed (``objectnav_success``,
    ``objectnav_spl``, ``objectnav_softspl``, ``objectnav_distance``): means over episodes."""
    cols = {"success": "objectnav_success", "spl": "objectnav_spl", "softspl": "objectnav_softspl",
            "distance_m": "objectnav_distance"}
    return tasks.groupby(["world", "policy", "mapper", "seed"])[list(cols)].mean().rename(columns=cols).reset_index()
