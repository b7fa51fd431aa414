"""What a new user trips over: overrides, keys, bad input before anything is written,
silent overwrites, seeds independent of their batch-mates, interrupted sessions."""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
import re
import signal
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pandas as pd
import pytest
from conftest import SMALL_RUN, one_line_error

from rosmeery_jax.apps.cli import main
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import EnvConfig, make

# One session setting for the module's sessions (the kill-9 test's child included: it inherits
# conftest's one host device), so they share one compiled function through the persistent cache.
RUN = SMALL_RUN
_one_line_error = one_line_error


# --- overrides and keys ---

def test_overrides_reach_any_depth_and_are_type_checked():
    env = make("small_office", knowledge__coverage__soft=True, camera__cull=64)
    assert env.config.knowledge.coverage.soft is True and env.config.camera.cull == 64
    with pytest.raises(InputError, match="knowledge__coverage__sof: unknown option 'sof'"):
        make("small_office", knowledge__coverage__sof=True)
    with pytest.raises(InputError, match=r"camera__cull: '64' is not of type int"):
        make("small_office", camera__cull="64")
    with pytest.raises(InputError, match="robot__max_speed: True is not of type float"):
        make("small_office", robot__max_speed=True)
    with pytest.raises(InputError, match="must be a finite number"):
        make("small_office", robot__max_speed=float("nan"))


@pytest.mark.parametrize("key, value, needle", [
    ("robot__max_speed", -1.0, "must be a number > 0"), ("robot__control_dt", 0.0, "must be a number > 0"),
    ("robot__substeps", 0, "a whole number >= 1"), ("nav__recoveries", -1, "a number >= 0"),
    ("mapping__miss", 0.4, "a number < 0"), ("camera__hfov", 3.2, "(0, pi)"), ("laser__min_range", 20.0,
    "below laser__max_range"), ("mapping__threshold", 5.0, "below mapping__clamp"),
    ("knowledge__min_fraction", 1.5, "[0, 1]"),
])
def test_settings_out_of_their_range_are_refused_by_name(key, value, needle):
    """They were taken: a negative top speed, a control period of 0 (a division by zero later)."""
    with pytest.raises(InputError) as err:
        EnvConfig().with_overrides("my.toml", **{key: value})
    assert str(err.value).startswith(f"my.toml: {key}: ") and needle in str(err.value)


def test_every_numeric_setting_has_a_range():
    """A new setting cannot go unchecked: each number is in LIMITS or checked in with_overrides."""
    from rosmeery_jax.env.config import LIMITS

    def numbers(obj, prefix=""):
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if dataclasses.is_dataclass(v):
                yield from numbers(v, f"{prefix}{f.name}__")
            elif isinstance(v, (int, float)) and not isinstance(v, bool):
                yield prefix + f.name

    elsewhere = {"robot__near_proxies", "laser__beams", "camera__width", "camera__height", "camera__rgb_width",
                 "camera__rgb_height"}
    assert set(numbers(EnvConfig())) == set(LIMITS) | elsewhere
    EnvConfig().with_overrides("defaults")  # every default within its range


def test_robot_dimensions_have_one_source():
    env = make("small_office", robot__radius=0.3)
    assert env.world.config.robot_radius == 0.3  # the free-space map was built for the wider robot
    assert env.world.free_space.reachable.sum() < make("small_office").world.free_space.reachable.sum()
    with pytest.raises(InputError, match="other robot or camera dimensions"):
        make(make("small_office").world, robot__radius=0.3)


def test_the_reset_key_sets_the_start_heading_bitwise():
    env = make("small_office")
    reset = jax.jit(jax.vmap(env.reset))
    keys = jax.vmap(jax.random.key)(np.arange(4))
    a, b = reset(keys), reset(keys)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        if not jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))  # same key: bitwise the same
    yaw = np.asarray(a.pose[:, 2])
    assert len(set(yaw.tolist())) == 4  # different keys: different starts
    spawn = make("small_office", start_yaw="spawn")
    assert np.all(np.asarray(jax.jit(jax.vmap(spawn.reset))(keys).pose[:, 2]) == np.float32(spawn.world.spawn[2]))


# --- session configs: everything checked before anything is written ---

@pytest.mark.parametrize("toml, field", [
    ("[env]\ncamera__cul = 3\n", "env.camera.cul: unknown option"),
    ("[env]\ncamera = {cull = 'many'}\n", "env.camera.cull: 'many' is not"),  # named as the file spells it
    ("[env.robot]\nmax_speed = -1.0\n", "env.robot.max_speed: -1.0 must be a number > 0"),
    ("seeds = true\n", "seeds"),
    ("devices = -1\n", "devices"),
    ("worlds = 5\n", "worlds"),
    ("worlds = []\n", "worlds"),
    ("metrics = []\n", "metrics"),
    ("duration = inf\n", "duration"),
    ("seeds = 10000\nduration = 600\n", "duration"),
    ("duration = 1e12\n", "duration"),
    ("seeds = 2\n[session]\nduration = 4\n", "seeds"),  # a key outside the [session] table
    ("worlds = ['small_office', 'x/small_office.xml']\n", "worlds"),
])
def test_bad_configs_are_refused_before_writing(tmp_path, capsys, toml, field):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "small_office.xml").write_bytes(
        (Path(__file__).parents[1] / "worlds" / "small_office.xml").read_bytes())
    path = tmp_path / "session.toml"
    path.write_text(toml.replace("x/", f"{tmp_path}/x/"))
    assert main(["run", "--config", str(path), "--out", str(tmp_path / "o"), "--detector", "off"]) == 2
    _one_line_error(capsys, str(path), field)
    assert not (tmp_path / "o").exists()


def test_a_session_checks_a_config_nobody_validated_and_only_once(tmp_path, monkeypatch):
    """``Session(cfg)`` as docs/api.md writes it: a config never validated ran with 0 seeds
    and wrote a results folder of nothing; a validated one is not checked again."""
    from rosmeery_jax import Session, SessionConfig

    cfg = SessionConfig(worlds=("small_office",), policies=("random",), seeds=0, duration=2.0, detector="off",
                        out=str(tmp_path / "o"))
    with pytest.raises(InputError, match="seeds: 0 must be a whole number >= 1"):
        Session(cfg)
    assert not (tmp_path / "o").exists()
    good = dataclasses.replace(cfg, seeds=1).validate()
    calls = []
    monkeypatch.setattr(SessionConfig, "validate", lambda self, source="config": calls.append(source) or self)
    Session(good)
    Session(dataclasses.replace(good, seeds=2))  # a changed copy is checked again
    assert calls == ["config"]
    with pytest.raises(TypeError, match="Session takes a SessionConfig, not dict"):  # an AttributeError
        Session({"worlds": ["small_office"]})
    with pytest.raises(TypeError, match="resume takes True or False, not 'no'"):  # "no" was true
        Session(good).run(resume="no")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("field, value, needle", [
    ("worlds", "small_office", "worlds: 'small_office' must be a tuple of names (one name: ('small_office',))"),
    ("seeds", 2.5, "seeds: 2.5 is not of type int"), ("seeds", True, "seeds: True is not of type int"),
    ("duration", "10", "duration: '10' is not of type float"),  # a TypeError deep in the checks
    ("duration", float("inf"), "duration: inf must be a finite number"), ("env", [], "env: [] must be a dict"),
])
def test_a_python_built_config_of_the_wrong_types_is_one_error_naming_the_field(tmp_path, field, value, needle):
    """The file and command-line loaders check types as they read; a SessionConfig built in
    Python is checked by ``validate`` (a string for worlds was read as one world a letter)."""
    from rosmeery_jax import SessionConfig

    cfg = SessionConfig(worlds=("small_office",), policies=("random",), detector="off", out=str(tmp_path / "o"))
    with pytest.raises(InputError, match=re.escape(needle)):
        dataclasses.replace(cfg, **{field: value}).validate()
    ok = dataclasses.replace(cfg, worlds=["small_office"], out=tmp_path / "o", duration=10).validate()
    assert ok.worlds == ("small_office",) and ok.out == str(tmp_path / "o")  # a list and a Path, as Python writes
    assert json.loads(json.dumps(dataclasses.asdict(ok)))["out"] == ok.out  # config.json could not hold a Path


def test_non_utf8_toml_and_bad_out_are_one_line(tmp_path, capsys):
    path = tmp_path / "s.toml"
    path.write_bytes("seeds = 2 # caf\xe9\n".encode("latin-1"))
    assert main(["run", "--config", str(path)]) == 2
    _one_line_error(capsys, "s.toml", "not UTF-8")
    target = tmp_path / "a_file"
    target.write_text("x")
    assert main([*RUN, "--out", str(target)]) == 2
    _one_line_error(capsys, "a_file", "is a file")


def test_a_folder_without_config_or_with_a_corrupt_one_is_refused(tmp_path, capsys):
    stray = tmp_path / "stray"
    (stray / "runs").mkdir(parents=True)
    (stray / "runs" / "small_office__random.metrics.csv").write_text("old")
    assert main([*RUN, "--out", str(stray), "--resume"]) == 2
    _one_line_error(capsys, "no config.json")
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "config.json").write_text("{not json")
    assert main([*RUN, "--out", str(corrupt), "--resume"]) == 2
    _one_line_error(capsys, "config.json", "cannot resume")


@pytest.fixture(scope="module")
def two_seeds(tmp_path_factory):
    out = tmp_path_factory.mktemp("hard") / "two"
    assert main([*RUN, "--seeds", "2", "--metrics", "ori,opi", "--out", str(out)]) == 0
    return out


def test_resume_refuses_changed_metrics_and_changed_world_files(two_seeds, tmp_path, capsys):
    assert main([*RUN, "--seeds", "2", "--metrics", "ori", "--out", str(two_seeds), "--resume"]) == 2
    _one_line_error(capsys, "metrics")
    cfg = json.loads((two_seeds / "config.json").read_text())
    cfg["inputs"]["worlds"]["small_office"] = "0" * 64  # as if the world file had been edited since
    copy = tmp_path / "copy"
    copy.mkdir()
    (copy / "config.json").write_text(json.dumps(cfg))
    assert main([*RUN, "--seeds", "2", "--metrics", "ori,opi", "--out", str(copy), "--resume"]) == 2
    _one_line_error(capsys, "inputs.worlds", "small_office has changed")


def test_result_files_follow_the_umask(two_seeds):
    umask = os.umask(0)
    os.umask(umask)
    for name in ("metrics.csv", "config.json", "runs/small_office__random.metrics.csv"):
        assert (two_seeds / name).stat().st_mode & 0o777 == 0o666 & ~umask, name


def test_replay_and_plot_never_overwrite_or_trace(two_seeds, tmp_path, capsys):
    poses = tmp_path / "p.csv"
    poses.write_text("t,x,y,yaw\n0,0,0,0\n1,0.1,0,0\n")
    before = (two_seeds / "metrics.csv").read_bytes()
    assert main(["replay", "--world", "small_office", "--poses", str(poses), "--out", str(two_seeds)]) == 2
    _one_line_error(capsys, "never overwritten")
    assert (two_seeds / "metrics.csv").read_bytes() == before
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "metrics.csv").write_text("world,policy\nx,y\n")
    assert main(["plot", str(bad)]) == 2
    _one_line_error(capsys, "metrics.csv", "columns")


def test_two_replay_entries_are_refused(tmp_path, capsys):
    rec = tmp_path / "r.jsonl"
    rec.write_text("{}\n")
    assert main(["run", "--worlds", "small_office", "--policies", f"replay:{rec},random,replay:{rec}",
                 "--out", str(tmp_path / "o"), "--detector", "off"]) == 2
    _one_line_error(capsys)
    assert not (tmp_path / "o").exists()


# --- results independent of batch-mates ---

def test_a_seed_does_not_depend_on_its_batch_mates(two_seeds, tmp_path):
    nine = tmp_path / "nine"  # two blocks of envs per policy instead of one
    assert main([*RUN, "--seeds", "9", "--metrics", "ori,opi", "--out", str(nine)]) == 0
    for table in ("metrics.csv", "trajectories.csv"):
        a = pd.read_csv(two_seeds / table)
        b = pd.read_csv(nine / table)
        b = b[b.seed < 2].reset_index(drop=True)
        pd.testing.assert_frame_equal(a, b, check_exact=True)


def test_frontier_nearest_leaves_the_spawn_in_every_seed(tmp_path):
    out = tmp_path / "fn"
    assert main(["run", "--worlds", "small_office", "--policies", "frontier_nearest", "--seeds", "4", "--duration",
                 "20", "--detector", "off", "--metrics", "ori", "--out", str(out), "--quiet"]) == 0
    t = pd.read_csv(out / "trajectories.csv")
    for seed, g in t.groupby("seed"):
        assert np.hypot(g.x - g.x.iloc[0], g.y - g.y.iloc[0]).max() > 1.0, seed


# --- interrupted sessions ---

def test_kill_9_then_resume_gives_the_files_of_an_uninterrupted_run(tmp_path):
    args = [*RUN[1:], "--seeds", "2", "--metrics", "ori"]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main(["run", *args, "--out", str(whole)]) == 0
    # A session writes its runs one after another once the batch is simulated: this one is
    # killed (SIGKILL, no clean-up) right after its first run's files are written.
    killer = ("import os, signal, sys\n"
              "from rosmeery_jax.session import runner\n"
              "write = runner.write_run\n"
              "def write_then_die(*a, **k):\n"
              "    write(*a, **k)\n"
              "    os.kill(os.getpid(), signal.SIGKILL)\n"
              "runner.write_run = write_then_die\n"
              "from rosmeery_jax.apps.cli import main\n"
              "sys.exit(main(sys.argv[1:]))\n")
    proc = subprocess.run([sys.executable, "-c", killer, "run", *args, "--out", str(cut)],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    assert proc.returncode == -signal.SIGKILL
    assert (cut / "runs" / "small_office__random.metrics.csv").exists()
    assert not (cut / "runs" / "small_office__frontier.metrics.csv").exists()
    assert main(["run", *args, "--out", str(cut), "--resume"]) == 0
    files = sorted(p.relative_to(whole) for p in whole.rglob("*") if p.is_file() and "timing" not in p.name
                   and p.suffix != ".png")
    assert files == sorted(p.relative_to(cut) for p in cut.rglob("*") if p.is_file() and "timing" not in p.name
                           and p.suffix != ".png")
    for f in files:
        if f.name != "config.json":
            assert (whole / f).read_bytes() == (cut / f).read_bytes(), f


# --- weights never execute code ---

class _Trap:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.mark.parametrize("kind", ["raw pickle", "zip checkpoint"])
def test_booby_trapped_weights_run_nothing(tmp_path, capsys, kind):
    torch = pytest.importorskip("torch")
    marker, weights = tmp_path / "PWNED", tmp_path / "trap.pt"
    if kind == "raw pickle":
        weights.write_bytes(pickle.dumps({"model": _Trap(marker)}))
    else:
        torch.save({"model": _Trap(marker)}, weights)
    assert main(["detector", "eval", "--weights", str(weights)]) == 2
    _one_line_error(capsys, "trap.pt")
    assert not marker.exists()


# --- world files ---

def test_loading_scales_and_matches_the_dense_test(write_world):
    """The KD-tree sample culling equals the dense points x boxes test on a paper world."""
    from rosmeery_jax.world import load_world
    from rosmeery_jax.world.surface import sample_boxes

    w = load_world("large_office")
    s = sample_boxes(w.scene, np.flatnonzero(w.scene.object_id >= 0), 400.0)
    p = s.points.astype(np.float64)
    dense = (w.scene.inside(p, margin=1e-4) & (np.arange(w.scene.num_boxes)[None] != s.box[:, None])).any(1)
    np.testing.assert_array_equal(w.scene.inside_any(p, margin=1e-4, skip=s.box), dense)


def test_declared_requirements_and_docs_stand_alone():
    from importlib import metadata

    numpy = [r for r in metadata.requires("rosmeery-jax") if r.startswith("numpy")]
    assert numpy == ["numpy>=2.0"]  # the code calls np.trapezoid (NumPy 2)
    root = Path(__file__).resolve().parents[1]
    for path in [*root.joinpath("rosmeery_jax").rglob("*.py"), root / "README.md", *root.joinpath("docs").glob("*.md")]:
        text = path.read_text(encoding="utf-8")
        for outside in ("SPEC section", "PERF-NOTES", "../shared"):
            assert outside not in text, (path, outside)  # users have only this repository
    readme = (root / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) < 300  # a user's guide; topics live in docs/
    for page in (root / "docs").glob("*.md"):
        assert len(page.read_text(encoding="utf-8").splitlines()) <= 300, page.name  # a reference, not a record
        assert page.name in readme or any(page.name in p.read_text() for p in root.joinpath("docs").glob("*.md")
                                          if p != page), f"{page.name} is linked from nowhere"


def test_every_link_and_picture_of_the_docs_resolves():
    """Relative links and pictures in the README, the changelog and docs/ name files that exist,
    relative to the page (as a repository browser resolves them)."""
    import re

    root = Path(__file__).resolve().parents[1]
    pages = [root / "README.md", root / "CHANGELOG.md", *root.joinpath("docs").glob("*.md"),
             *root.glob("experiments/*/README.md"), root / "detector" / "README.md"]
    broken = [(page.name, target) for page in pages
              for target in re.findall(r"\]\(([^)#\s]+)", page.read_text(encoding="utf-8"))
              if "://" not in target and not (page.parent / target).exists()]
    assert len(pages) > 10 and not broken, broken


def test_output_closed_by_its_reader_is_one_line_not_a_write_error(monkeypatch, capsys):
    class ClosedPipe:  # stdout after `| head` has read its lines and left
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert main(["worlds"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == "rosmeery: stopped: the program reading its output closed it"
