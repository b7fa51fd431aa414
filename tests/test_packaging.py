"""A plain (non-editable) install works: the wheel carries the worlds, taxonomy, schema,
teleop page and weights, and the installed package finds them away from the repository."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_a_built_wheel_installed_outside_the_repo_finds_its_worlds(tmp_path):
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(wheels), str(ROOT)], check=True, cwd=tmp_path)
    wheel = next(wheels.glob("rosmeery_jax-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for world in ("kitchen", "laboratory", "small_office", "large_office"):
        assert f"rosmeery_jax/builtin_worlds/{world}.xml" in names  # from the top-level worlds/
    packages = {p.parent.relative_to(ROOT).as_posix() for p in (ROOT / "rosmeery_jax").rglob("__init__.py")}
    assert {p for p in packages if f"{p}/__init__.py" not in names} == set()  # pyproject lists every package
    assert {"rosmeery_jax/world/taxonomy.toml", "rosmeery_jax/metrics/semantic_map.schema.json", "rosmeery_jax/apps/teleop/static/app.js",
            "rosmeery_jax/detector/weights/yolov5n_procedural.pt",
            "rosmeery_jax/detector/weights/yolov5n_paper_worlds.pt"} <= names
    site = tmp_path / "site"  # a fresh install target: the package from the wheel, nothing from the repo
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site), str(wheel)],
                   check=True, cwd=tmp_path)
    code = ("import rosmeery_jax, pathlib; from rosmeery_jax.world import load_world, world_names; "
            "assert pathlib.Path(rosmeery_jax.__file__).is_relative_to(pathlib.Path(r'%s')), rosmeery_jax.__file__; "
            "print(','.join(world_names()), load_world('kitchen').truth.num_objects)" % site)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path,
                         env={"PYTHONPATH": str(site), "PATH": "/usr/bin:/bin", "JAX_PLATFORMS": "cpu"})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-2:] == ["kitchen,laboratory,small_office,large_office", "35"]


def _closure(requirements: list[str]) -> set[str]:
    """The distributions a plain install of ``requirements`` brings: them and, installed here,
    what each declares in turn (extras and markers of other platforms left out)."""
    from importlib import metadata

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    seen: set[str] = set()
    todo = list(requirements)
    while todo:
        req = Requirement(todo.pop())
        name = canonicalize_name(req.name)
        if name in seen or (req.marker and not req.marker.evaluate({"extra": ""})):
            continue
        seen.add(name)
        try:
            todo += metadata.requires(name) or []
        except metadata.PackageNotFoundError:  # not installed here: nothing of it can be imported either
            pass
    return seen


# A plain install seen from this environment: a module of a distribution outside ``argv[1]``
# cannot be imported (as if not installed); packages that only try such an import go on.
_PLAIN_INSTALL = """
import importlib.abc, json, sys
from importlib import metadata
from packaging.utils import canonicalize_name
allowed, dists = set(json.loads(sys.argv[1])), metadata.packages_distributions()
class Undeclared(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        top = name.split(".")[0]
        if dists.get(top) and not {canonicalize_name(d) for d in dists[top]} & allowed:
            raise ModuleNotFoundError(f"No module named {top!r}", name=top)
sys.meta_path.insert(0, Undeclared())
import rosmeery_jax.apps.cli, rosmeery_jax.session, rosmeery_jax.gym, rosmeery_jax.rl.ppo
print("gymnax" in sys.modules and "mujoco" in sys.modules)
"""


def test_what_rosmeery_run_imports_is_declared():
    """`pip install .` gets what pyproject declares and what that declares in turn, not what
    the test extras bring along: what `rosmeery run` and `rosmeery train` import (the command
    line, sessions, the gym and RL environments, the trainer) imports with nothing else
    installed (gymnax 0.0.9 imports six, which only a test extra's dependency had brought)."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = _closure(project["dependencies"] + project["optional-dependencies"]["detector"]) | {"rosmeery-jax"}
    out = subprocess.run([sys.executable, "-c", _PLAIN_INSTALL, json.dumps(sorted(declared))], capture_output=True,
                         text=True, cwd=ROOT, env={"PATH": "/usr/bin:/bin", "JAX_PLATFORMS": "cpu"})
    assert out.returncode == 0, out.stderr.strip().splitlines()[-1]
    assert out.stdout.split()[-1] == "True"  # the import reached the heavy parts


def test_without_the_detector_extra_the_commands_that_run_yolo_are_one_line_naming_it(tmp_path, capsys, monkeypatch):
    """torch and ONNX Runtime are imported only when YOLO runs: without them, each command
    that would run or export it stops before any work, naming all it lacks and what to
    install (tracebacks before, teleop's after compiling; a session named torch alone)."""
    import importlib.util

    from rosmeery_jax.apps.cli import main

    found = importlib.util.find_spec
    extra = {"torch", "onnxruntime", "onnx", "onnxscript"}
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name in extra else found(name, *a))
    monkeypatch.chdir(tmp_path)
    cases = {("detector", "train", "--data", "d", "--out", "w.pt"): "detector train: needs torch (the detector extra)",
             ("detector", "eval"): "detector eval: needs torch, onnxruntime, onnx, onnxscript (the detector extra)",
             ("detector", "eval", "--runtime", "torch"): "detector eval: needs torch (the detector extra)",
             ("detector", "export", "--out", "x.onnx"): "detector export: needs torch, onnx, onnxscript (the detector",
             ("teleop", "--world", "kitchen"): "--detector: 'yolo' needs torch, onnxruntime, onnx, onnxscript (the",
             ("run", "--worlds", "kitchen"): "detector: 'yolo' needs torch, onnxruntime, onnx, onnxscript (the"}
    for argv, needle in cases.items():
        assert main(list(argv)) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith(f"rosmeery: error: command line: {needle}") and err.count("\n") == 1, err
        assert "pip install 'rosmeery-jax[detector]' 'torch==2.13.0'" in err
    assert err.endswith("(or use --detector oracle / off)\n") and not list(tmp_path.iterdir())  # nothing written
    assert main(["teleop", "--world", "kitchen", "--detector", "oracle", "--port", "0"]) == 2  # the oracle needs
    assert "--port: 0 is not a TCP port" in capsys.readouterr().err  # none of it: teleop goes on to its next check
