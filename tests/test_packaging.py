"""A plain (non-editable) install works: the wheel carries the worlds, taxonomy, schema,
teleop page and weights, and the installed package finds them away from the repository."""

from __future__ import annotations

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
        assert f"rosmeery_jax/world/builtin/{world}.xml" in names
    assert {"rosmeery_jax/world/taxonomy.toml", "rosmeery_jax/apps/teleop/static/app.js",
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
