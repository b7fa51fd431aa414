"""Object-goal episodes and the map-use metrics, on a built hall whose distances are worked
out by hand: cell centres lie at -4.575 + 0.05 k m, a chair box B spans x 2.3-2.7 (its west
face's samples lie in the cells centred at x = 2.325, so its success region starts at the
cell centre x = 1.325, 1 m away), a copy A of it shifted 4.525 m west spans x -2.225 to
-1.825 (its east face's cells centred at -1.825: its approach region ends at x = -0.825),
and the start cell's centre is x = 0.025, on the same row."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from conftest import one_line_error, room_xml

from rosmeery_jax.apps.cli import main
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.metrics import tasks
from rosmeery_jax.world import episodes, geodesic, load_world
from rosmeery_jax.world.episodes import Episode
from rosmeery_jax.world.freespace import FreeSpace

CHAIR = '<body name="chair_1" pos="2.5 0 0"><geom type="box" pos="0 0 0.2" size="0.2 0.2 0.2"/></body>'
DESK = '<body name="desk_1" pos="0 3 0"><geom type="box" pos="0 0 0.3" size="0.4 0.3 0.3"/></body>'
START = (0.03, 0.03, 0.0)  # the cell whose centre is (0.025, 0.025)


@pytest.fixture(scope="module")
def hall(tmp_path_factory):
    path = tmp_path_factory.mktemp("tasks") / "hall.xml"
    path.write_text(room_xml(CHAIR + DESK, {"chair_1": "chair", "desk_1": "desk"}, spawn=(0.0, -2.0, 0.0), half=4.0))
    return load_world(path)


def _chair_points(world, shift: float = 0.0) -> np.ndarray:
    t = world.truth
    pts = np.asarray(t.samples.points, np.float64)[np.asarray(t.samples.object) == t.names.index("chair_1")]
    return pts + [shift, 0.0, 0.0]


def _episode(world) -> Episode:
    return Episode(0, START, "chair", float(episodes.regions(world).distance["chair"][world.free_space.cell(START[:2])]))


def _score(world, parts: list[tuple[np.ndarray, str | None]], attempts: int = 3):
    points = np.concatenate([p for p, _ in parts]) if parts else np.zeros((0, 3))
    instance = np.concatenate([np.full(len(p), k) for k, (p, _) in enumerate(parts)]) if parts else np.zeros(0, int)
    return tasks.score(world, [_episode(world)], points, instance, {k: c for k, (_, c) in enumerate(parts)}, attempts)


def test_the_shortest_distance_is_the_hand_computed_one(hall):
    assert _episode(hall).geodesic_distance == pytest.approx(1.3, abs=1e-9)


def test_a_perfect_map_succeeds_with_spl_one_on_a_straight_path(hall):
    r = _score(hall, [(_chair_points(hall), "chair")])
    assert r.values == pytest.approx({"task_success": 1.0, "task_spl": 1.0, "task_softspl": 1.0,
                                      "task_distance": 0.0})
    assert r.path[0] == pytest.approx(1.3, abs=1e-9)


def test_a_chair_labelled_a_cabinet_fails_the_chair_query(hall):
    r = _score(hall, [(_chair_points(hall), "cabinet")])
    assert r.values == pytest.approx({"task_success": 0.0, "task_spl": 0.0, "task_softspl": 0.0,
                                      "task_distance": 1.3}, abs=1e-9)
    assert r.instance[0] == -1 and r.path[0] == 0.0


def test_a_shifted_instance_fails_first_and_the_true_one_succeeds_second(hall):
    """A (shifted) is nearer: 0.85 m to its approach region, then 2.15 m on to B's: l = 3.0."""
    both = [(_chair_points(hall, -4.525), "chair"), (_chair_points(hall), "chair")]
    r = _score(hall, both)
    assert r.success[0] and r.instance[0] == 1
    assert r.path[0] == pytest.approx(0.85 + 2.15, abs=1e-9)
    assert r.values["task_spl"] == pytest.approx(1.3 / 3.0, abs=1e-9)
    once = _score(hall, both, attempts=1)  # only A tried: it stops 2.15 m short of the region
    assert not once.success[0] and once.instance[0] == 0
    assert once.values["task_distance"] == pytest.approx(2.15, abs=1e-9)
    assert once.values["task_softspl"] == 0.0  # it moved away from the goal: no progress


def test_an_empty_map_scores_zero_and_no_nan(hall):
    r = _score(hall, [])
    assert r.values == pytest.approx({"task_success": 0.0, "task_spl": 0.0, "task_softspl": 0.0,
                                      "task_distance": 1.3}, abs=1e-9)


def test_geodesic_distance_goes_around_a_wall_by_hand():
    ok = np.ones((5, 9), bool)
    ok[:4, 4] = False  # a wall with a gap in the top row
    fs = FreeSpace(np.zeros(2), 1.0, ~ok, ok, ok, ok.astype(np.float32))
    d = geodesic.field(geodesic.graph(fs), np.array([[0, 0]]))
    assert d[0, 3] == 3.0 and d[4, 0] == 4.0 and d[1, 1] == pytest.approx(np.sqrt(2))
    # (0, 0) to (0, 8) through the gap at (4, 4), no diagonal past the wall's corner: 3 diagonals and
    # a step to (4, 3), two steps to (4, 5), 3 diagonals and a step up to (0, 8)
    assert d[0, 8] == pytest.approx(6 * np.sqrt(2) + 4)
    assert np.isinf(d[0, 4])


def test_generated_episodes_are_the_same_bytes_for_the_same_seed_and_cover_every_goal(hall, tmp_path):
    a, b = episodes.generate(hall, 6, 3), episodes.generate(hall, 6, 3)
    episodes.write(tmp_path / "a.json", hall, a, 3)
    episodes.write(tmp_path / "b.json", hall, b, 3)
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert {e.goal for e in a} == {"chair", "desk"}
    assert all(e.geodesic_distance >= episodes.MIN_DISTANCE for e in a)
    assert episodes.read(tmp_path / "a.json", hall) == a  # read back, the distances computed again
    assert episodes.generate(hall, 6, 4) != a


def _file(tmp_path, world, change) -> str:
    doc = {"format": "rosmeery-objectnav", "version": 1, "world": world.name, "seed": 0,
           "episodes": [{"id": 0, "start": list(START), "goal": "chair"}]}
    change(doc)
    path = tmp_path / "eps.json"
    path.write_text(json.dumps(doc))
    return str(path)


@pytest.mark.parametrize("change, field", [
    (lambda d: d.update(world="kitchen"), "world"),
    (lambda d: d["episodes"][0].update(goal="toilet"), "episodes[0].goal"),
    (lambda d: d["episodes"][0].update(start=[2.5, 0.0, 0.0]), "episodes[0].start"),  # inside the chair
    (lambda d: d["episodes"][0].update(start=[float("nan"), 0.0, 0.0]), "episodes[0].start"),
    (lambda d: d.update(episodes=[d["episodes"][0]] * 10_001), "episodes"),
])
def test_a_bad_episode_file_is_one_line_naming_the_field(hall, tmp_path, capsys, change, field):
    ply, out = _map_files(hall, tmp_path)
    assert main(["evaluate", "--world", str(hall.path), "--map", str(ply), "--metrics", "task",
                 "--episodes", _file(tmp_path, hall, change), "--out", str(out)]) == 2
    one_line_error(capsys, "eps.json", field)
    assert not out.exists()


@pytest.mark.parametrize("attempts", ["0", "-1"])
def test_attempts_must_be_at_least_one(hall, tmp_path, capsys, attempts):
    ply, out = _map_files(hall, tmp_path)
    assert main(["evaluate", "--world", str(hall.path), "--map", str(ply), "--metrics", "task",
                 "--task-attempts", attempts, "--out", str(out)]) == 2
    one_line_error(capsys, "--task-attempts")
    assert not out.exists()


def _map_files(world, tmp_path):
    pts = _chair_points(world)
    ply = tmp_path / "map.ply"
    header = (f"ply\nformat ascii 1.0\nelement vertex {len(pts)}\nproperty float x\nproperty float y\n"
              "property float z\nproperty int instance\nend_header\n")
    ply.write_text(header + "".join(f"{x} {y} {z} 0\n" for x, y, z in pts))
    ply.with_suffix(".json").write_text(json.dumps({"frame": {"world": world.name, "time_s": 1.0},
                                                    "objects": [{"id": 0, "label": "chair"}]}))
    return ply, tmp_path / "out"


def test_evaluate_scores_the_task_metrics_by_name(hall, tmp_path, capsys):
    ply, out = _map_files(hall, tmp_path)
    eps = tmp_path / "set.json"
    assert main(["tasks", "--world", str(hall.path), "--episodes", "4", "--seed", "1", "--out", str(eps)]) == 0
    assert main(["evaluate", "--world", str(hall.path), "--map", str(ply), "--metrics", "ori,task",
                 "--episodes", str(eps), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    chairs = sum(e["goal"] == "chair" for e in json.loads(eps.read_text())["episodes"])
    assert summary["task_success"] == pytest.approx(chairs / 4)  # the desk is not in the map
    assert main(["tasks", "--world", str(hall.path), "--episodes", "4", "--out", str(eps)]) == 2  # never replaced
    one_line_error(capsys, "set.json", "exists")


@pytest.mark.parametrize("setting, value", [("task_attempts", 0), ("task_attempts", -1), ("task_attempts", 1.5),
                                            ("task_episodes", 0), ("task_episodes", 10 ** 6)])
def test_a_session_refuses_bad_task_settings_naming_them(hall, setting, value):
    from rosmeery_jax.session import SessionConfig

    with pytest.raises(InputError, match=setting):
        SessionConfig(worlds=(str(hall.path),), metrics=("ori", "task"), **{setting: value}).validate()


def test_a_map_scored_as_it_grows_scores_as_the_map_scored_at_once(hall):
    """The scorer keeps what it learnt of earlier maps: points added, instances merged and
    labels changed on the way give, at every step, what a fresh scorer gives that map."""
    rng = np.random.default_rng(0)
    a, b = _chair_points(hall, -4.525), _chair_points(hall)
    desk = np.asarray(hall.truth.samples.points, np.float64)[
        np.asarray(hall.truth.samples.object) == hall.truth.names.index("desk_1")]
    points = np.concatenate([a, b, desk])
    instance = np.repeat([0, 1, 2], [len(a), len(b), len(desk)])
    order = rng.permutation(len(points))
    points, instance = points[order], instance[order]
    eps = episodes.generate(hall, 6, seed=3)
    grown = tasks.TaskScorer(hall, eps)
    steps = [(40, {0: "chair", 1: "chair", 2: "desk"}), (200, {0: "chair", 1: "cabinet", 2: "desk"}),
             (len(points), {0: "chair", 1: "chair", 2: "chair"})]
    for end, labels in steps:
        got = grown.score(points[:end], instance[:end], labels)
        want = tasks.score(hall, eps, points[:end], instance[:end], labels)
        np.testing.assert_array_equal(got.path, want.path)
        np.testing.assert_array_equal(got.stop, want.stop)
        assert got.values == want.values
    merged = np.where(instance == 1, 0, instance)  # instances 0 and 1 become one
    got = grown.score(points, merged, {0: "chair", 2: "desk"})
    assert got.values == tasks.score(hall, eps, points, merged, {0: "chair", 2: "desk"}).values
    desk = np.array([e.goal == "desk" for e in eps])
    assert desk.any() and got.success[desk].all()  # the desk is untouched by the merge


def test_a_mappers_scorer_carries_the_task_metrics_of_its_map(hall):
    """The scorer a session gives each mapper (and the built-in knowledge) adds the task
    metrics of the map it scores: those of the same map scored alone, episodes the world's
    generated set."""
    from rosmeery_jax.mapping.protocol import MapState, OnlineScorer
    from rosmeery_jax.metrics.map_score import TOLERANCE

    names = hall.taxonomy.names
    scorer = OnlineScorer(hall, TOLERANCE, (), tasks.TaskQuery(tasks.TASK_METRICS, 6, 2))
    a, b = _chair_points(hall, -4.525), _chair_points(hall)
    points = np.concatenate([a, b])
    instance = np.repeat([0, 1], [len(a), len(b)])
    label = np.array([names.index("chair"), names.index("cabinet")], np.int32)
    for end in (len(a) // 2, len(points)):
        sc = scorer.score(MapState(points[:end], instance[:end], label, np.full(2, 0.9, np.float32)))
        want = tasks.score(hall, episodes.generate(hall, 6), points[:end], instance[:end],
                           {0: "chair", 1: "cabinet"}, attempts=2).values
        assert {n: sc.field[n] for n in tasks.TASK_METRICS} == want
    assert sc.field["task_success"] < 1  # the chair the map calls a cabinet is never sought


def test_a_robot_with_a_perfect_map_drives_to_every_goal(hall, tmp_path, monkeypatch, capsys):
    """Executed tasks (task "objectnav"): the built-in knowledge's final map replaced by the
    perfect one (every sample, its true label). Every episode of the open hall succeeds in
    one attempt, the navigator reaching its goal in the region; the robot drives at least
    the geodesic distance and not much more; tasks.csv holds one row per episode and seed,
    the same when the drives run again."""
    from rosmeery_jax.mapping.protocol import MapState
    from rosmeery_jax.session import objectnav

    t = hall.truth
    cats = np.array([hall.taxonomy.names.index(c) for c in t.categories], np.int32)
    perfect = MapState(np.asarray(t.samples.points), np.asarray(t.samples.object), cats, np.ones(len(cats), np.float32))
    monkeypatch.setattr(objectnav, "final_maps", lambda world, sim, j, mappers: {"oracle": perfect})
    real, twice = objectnav.for_group, []

    def driven_twice(*args):  # the task phase run again on the same exploration: the same rows
        first, again = real(*args), real(*args)
        for name in first:
            pd.testing.assert_frame_equal(first[name], again[name])
        twice.append(len(first))
        return first

    monkeypatch.setattr(objectnav, "for_group", driven_twice)
    assert main(["run", "--worlds", str(hall.path), "--policies", "frontier", "--seeds", "2", "--duration", "5",
                 "--detector", "off", "--task", "objectnav", "--task-episodes", "4", "--quiet",
                 "--out", str(tmp_path / "o")]) == 0
    assert twice == [1]
    assert "objectnav: 8 episodes driven in" in capsys.readouterr().out  # the session's summary says so
    df = pd.read_csv(tmp_path / "o" / "tasks.csv")
    assert len(df) == 2 * 4 and sorted(set(df.episode)) == [0, 1, 2, 3] and set(df.goal) == {"chair", "desk"}
    assert (df.success == 1).all() and (df.attempts == 1).all() and (df.distance_m == 0).all()
    assert (df.query_success == 1).all() and (df.navigator == "reached").all()
    assert (df.path_m >= df.shortest_m - 0.2).all() and (df.spl > 0.6).all()  # within the goal's tolerance
    means = objectnav.means(df)
    assert (means.objectnav_success == 1).all() and len(means) == 2


def test_a_task_the_session_does_not_know_is_one_line(hall, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", "--worlds", str(hall.path), "--task", "fetch", "--out", str(out)]) == 2
    one_line_error(capsys, "task", "'fetch' is not a task")
    assert not out.exists()


SEEKERS = """import numpy as np
from rosmeery_jax.gym import Agent

GOALS = {"chair": (1.6, 0.0, 0.0), "desk": (0.0, 2.0, np.pi / 2)}  # 0.7 m from each one's face


class Goer(Agent):
    name, camera = "goer", False

    def act(self, obs):
        return obs["pose"]  # stays where it is while exploring

    def seek(self, obs, goal):
        return np.tile(np.float32(GOALS[goal]), (len(obs["pose"]), 1)), obs["nav_status"][:, 0] == 2  # reached


class Quitter(Goer):
    name = "quitter"

    def seek(self, obs, goal):
        return obs["pose"], np.ones(len(obs["pose"]), bool)
"""


def test_a_python_agent_seeks_the_goals_itself(hall, tmp_path, capsys):
    """An agent's own task phase: put at each episode's start, it drives to a pose 0.7 m
    before the goal object and stops there (success, path at least the geodesic distance);
    one that stops at once is judged at the start (failure, path 0, distance the episode's
    geodesic distance)."""
    agents = tmp_path / "seekers.py"
    agents.write_text(SEEKERS)
    out = tmp_path / "o"
    assert main(["run", "--worlds", str(hall.path), "--policies", f"agent:{agents}:Goer,agent:{agents}:Quitter",
                 "--seeds", "2", "--duration", "2", "--detector", "off", "--task", "objectnav", "--task-episodes", "3",
                 "--quiet", "--out", str(out)]) == 0
    assert "objectnav: 12 episodes driven in" in capsys.readouterr().out
    df = pd.read_csv(out / "tasks.csv")
    assert len(df) == 2 * 2 * 3 and set(df.mapper) == {"own"} and (df.navigator == "stopped").all()
    assert (df.attempts == 1).all() and (df.instance == -1).all() and (df.query_success == -1).all()
    goer, quitter = df[df.policy == "goer"], df[df.policy == "quitter"]
    assert (goer.success == 1).all() and (goer.path_m >= goer.shortest_m).all() and (goer.spl > 0.5).all()
    assert np.allclose(goer[["stop_x", "stop_y"]].to_numpy(), [[1.6, 0.0] if g == "chair" else [0.0, 2.0]
                                                            for g in goer.goal], atol=0.25)
    assert (quitter.success == 0).all() and (quitter.path_m == 0).all() and (quitter.time_s == 0).all()
    np.testing.assert_allclose(quitter.distance_m, quitter.shortest_m, atol=1e-4)  # episodes keep 4 decimals
    np.testing.assert_allclose(quitter[["stop_x", "stop_y"]], quitter[["start_x", "start_y"]], atol=1e-6)


@pytest.mark.parametrize("body, needle", [
    ("", "has no task phase (implement seek(obs, goal) -> (actions, stop))"),
    ("    def seek(self, obs, goal):\n        return obs['pose']\n", "seek must return (actions, stop)"),
    ("    def seek(self, obs, goal):\n        return obs['pose'], np.zeros(1, int)\n", "stop must be 1 booleans"),
])
def test_an_agent_without_a_working_seek_is_one_line(hall, tmp_path, capsys, body, needle):
    agent = tmp_path / "a.py"
    agent.write_text("import numpy as np\nfrom rosmeery_jax.gym import Agent\nclass A(Agent):\n    name = 'a'\n"
                     "    camera = False\n    def act(self, obs):\n        return obs['pose']\n" + body)
    out = tmp_path / "o"
    assert main(["run", "--worlds", str(hall.path), "--policies", f"agent:{agent}:A", "--seeds", "1", "--duration",
                 "1", "--detector", "off", "--task", "objectnav", "--task-episodes", "1", "--quiet", "--out",
                 str(out)]) == 2
    one_line_error(capsys, needle)
    assert not (out / "tasks.csv").exists() and not (out / "metrics.csv").exists()


def test_the_plan_drives_into_the_region_or_to_a_policys_own_goals(hall):
    """The built-in plan's goal for the chair lies on the start's row, the first cell 0.3 m
    from the nearest cell outside the chair's region (x = 1.275 + 0.3), facing the chair; a
    policy's ``task_goals`` replaces it, and a bad return is one error naming the plugin."""
    from rosmeery_jax.mapping.protocol import MapState
    from rosmeery_jax.session import objectnav

    chair = _chair_points(hall)
    m = MapState(chair, np.zeros(len(chair), np.int64), np.array([hall.taxonomy.names.index("chair")]),
                 np.ones(1, np.float32))
    scorer = tasks.TaskScorer(hall, [_episode(hall)])
    (copy,) = objectnav.plan(hall, scorer, m, 0, "oracle")
    assert copy.tries == 1 and copy.instance.tolist() == [0] and copy.query_success
    x, y, yaw = copy.goals[0]
    assert x == pytest.approx(1.275 + 0.3, abs=1e-5) and y == pytest.approx(0.025, abs=1e-5) and yaw == pytest.approx(0, abs=0.2)

    class Own:
        name = "own"

        def __init__(self, goals):
            self.goals = goals

        def task_goals(self, semantic_map, start, goal, attempts):
            return self.goals

    (copy,) = objectnav.plan(hall, scorer, m, 0, "oracle", Own([[1.0, 0.0, 0.0], [2.0, 0.5, 1.0]]), "own.py:Own")
    assert copy.goals.tolist() == [[1.0, 0.0, 0.0], [2.0, 0.5, 1.0]] and copy.instance.tolist() == [-1, -1]
    (copy,) = objectnav.plan(hall, scorer, m, 0, "oracle", Own(None), "own.py:Own")
    assert copy.instance.tolist() == [0]  # None: the built-in search
    for bad in ([[1.0, np.nan, 0.0]], [[0.0, 0.0, 0.0]] * 4, "north"):
        with pytest.raises(InputError, match="plugin 'own.py:Own': task_goals must return at most 3 finite"):
            objectnav.plan(hall, scorer, m, 0, "oracle", Own(bad), "own.py:Own")
