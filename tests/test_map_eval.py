"""Scoring a user's own semantic map: hand-computed cases, density, bad input."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import trimesh
from conftest import room_xml

from rosmeery_jax.apps.cli import main
from rosmeery_jax.metrics.indices import compute
from rosmeery_jax.metrics.map_score import read_map, score
from rosmeery_jax.sim.knowledge import GroundTruthTable
from rosmeery_jax.world import load_world

# A chair (0.4 m cube) and a bigger desk (0.6 m cube) in a 4 x 4 m room.
_BODIES = """
<body name="chair"><geom type="box" pos="-1 0 0.2" size="0.2 0.2 0.2"/></body>
<body name="desk"><geom type="box" pos="1 0 0.3" size="0.3 0.3 0.3"/></body>
"""


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    path = tmp_path_factory.mktemp("w") / "two.xml"
    path.write_text(room_xml(_BODIES, {"chair": "chair", "desk": "desk"}, spawn=(0.0, 1.0, 0.0)))
    return load_world(path)


def _write(tmp_path, world, points, instance, objects, stem="map", frame_world=None):
    cloud = trimesh.Trimesh(vertices=np.asarray(points, float), faces=np.zeros((0, 3), np.int64), process=False)
    cloud.vertex_attributes["object_id"] = np.asarray(instance, np.int32)
    ply = tmp_path / f"{stem}.ply"
    ply.write_bytes(trimesh.exchange.ply.export_ply(cloud, encoding="binary", include_attributes=True))
    meta = {"frame": {"world": frame_world or world.name, "time_s": 1.0},
            "objects": [{"id": i, "label": lab, "confidence": c} for i, (lab, c) in objects.items()]}
    ply.with_suffix(".json").write_text(json.dumps(meta))
    return ply


def _metrics(world, ply):
    sc = score(world, read_map(ply, world.taxonomy))
    t = world.truth
    table = GroundTruthTable(np.asarray(t.ps_G), np.asarray(t.num_predicates), np.asarray(t.category_index))
    return {k: float(v) for k, v in compute(sc.log, table).items()}, sc


def _parts(world):
    pts, obj = np.asarray(world.truth.samples.points), np.asarray(world.truth.samples.object)
    return pts[obj == 0], pts[obj == 1]  # chair, desk


def test_a_perfect_map_scores_one_and_a_denser_copy_scores_the_same(world, tmp_path):
    chair, desk = _parts(world)
    pts = np.concatenate([chair, desk])
    inst = np.r_[np.zeros(len(chair)), np.ones(len(desk))]
    m, sc = _metrics(world, _write(tmp_path, world, pts, inst, {0: ("chair", 1.0), 1: ("desk", 1.0)}))
    assert m == {"ori": 1.0, "cori": 1.0, "cori_any": 1.0, "opi": 1.0, "opi_strict": 1.0}
    assert sc.off_object == 0.0 and sc.unmatched == 0
    jitter = pts + 0.01  # every point twice, the copy 1.7 cm off: no sample is counted twice
    m2, _ = _metrics(world, _write(tmp_path, world, np.concatenate([pts, jitter]), np.r_[inst, inst],
                                   {0: ("chair", 1.0), 1: ("desk", 1.0)}, stem="dense"))
    assert m2["ori"] == 1.0


def test_evaluate_takes_a_world_file_and_map_files_and_refuses_no_maps_and_a_bad_tolerance(world, tmp_path):
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.metrics.map_score import evaluate

    chair, _ = _parts(world)
    m = read_map(_write(tmp_path, world, chair, np.zeros(len(chair)), {0: ("chair", 1.0)}), world.taxonomy)
    by_file = evaluate(str(world.path), [m])[3]  # a name or file, as load_world takes (was an AttributeError)
    assert by_file == evaluate(world, [m])[3] and by_file["ori"] > 0
    with pytest.raises(InputError, match="maps: is empty"):
        evaluate(world, [])
    assert evaluate(world, m.path)[3] == evaluate(world, [str(m.path)])[3] == by_file  # its file, alone or listed
    with pytest.raises(InputError, match=r"nope\.ply: file: not found"):
        evaluate(world, tmp_path / "nope.ply")  # a path was taken letter by letter (an AttributeError)
    for bad in (None, 3, [m, 3]):
        with pytest.raises(TypeError, match="evaluate: maps must be"):
            evaluate(world, bad)
    for bad in (0.0, -1.0, float("nan"), "0.05"):
        with pytest.raises(InputError, match="tolerance: .* must be a distance > 0"):
            evaluate(world, [m], tolerance=bad)


def test_merged_objects_lose_the_smaller_one(world, tmp_path):
    chair, desk = _parts(world)
    ply = _write(tmp_path, world, np.concatenate([chair, desk]), np.zeros(len(chair) + len(desk)), {0: ("desk", 1.0)})
    m, sc = _metrics(world, ply)
    assert len(desk) > len(chair) and list(sc.matched) == [-1, 0]
    assert m["ori"] == pytest.approx(0.5)  # 1 - mean(|ps_G - 0| / ps_G, 0)


def test_a_split_object_counts_only_its_matched_part(world, tmp_path):
    chair, desk = _parts(world)
    k = (2 * len(chair)) // 3
    inst = np.r_[np.zeros(k), np.full(len(chair) - k, 2), np.ones(len(desk))]
    ply = _write(tmp_path, world, np.concatenate([chair, desk]), inst,
                 {0: ("chair", 1.0), 2: ("chair", 1.0), 1: ("desk", 1.0)})
    m, sc = _metrics(world, ply)
    assert sc.unmatched == 1
    assert m["ori"] == pytest.approx(1 - 0.5 * (len(chair) - k) / len(chair), abs=1e-6)


def test_points_beyond_the_tolerance_lie_on_no_object(world, tmp_path):
    chair, desk = _parts(world)
    far = desk + np.array([0.0, 0.0, 3.0])  # the desk's cloud lifted 3 m: near no sample
    ply = _write(tmp_path, world, np.concatenate([chair, far]), np.r_[np.zeros(len(chair)), np.ones(len(desk))],
                 {0: ("chair", 1.0), 1: ("desk", 1.0)})
    m, sc = _metrics(world, ply)
    assert m["ori"] == pytest.approx(0.5)
    assert sc.off_object == pytest.approx(len(desk) / (len(chair) + len(desk)))


def test_a_wrong_label_keeps_ori_and_loses_cori_and_the_wrong_predicates(world, tmp_path):
    chair, desk = _parts(world)
    ply = _write(tmp_path, world, np.concatenate([chair, desk]), np.r_[np.zeros(len(chair)), np.ones(len(desk))],
                 {0: ("chair", 0.8), 1: ("chair", 0.9)})  # the desk called a chair
    m, _ = _metrics(world, ply)
    assert m["ori"] == pytest.approx(1.0)
    assert m["cori"] == pytest.approx(1 - 0.5 * ((1 - 0.8) + 1.0))  # chair: 0.8 of its samples; desk: none
    assert m["opi"] == pytest.approx(1.0)  # three predicates declared for each, as many as P_G
    # desk as chair: only is-a furniture holds; 2 missing + 2 false = 4 errors of 3 -> capped mean
    assert m["opi_strict"] == pytest.approx(1 - min(1.0, 0.5 * (0 + 4 / 3)))


@pytest.mark.parametrize("case, field", [
    ("garbage", "file"), ("no_instance", "vertex"), ("nan", "vertex x, y, z"),
    ("label", "objects[0].label"), ("world", "frame.world"), ("confidence", "vertex confidence"),
    ("fraction", "vertex object_id"), ("ascii_nan", "vertex"), ("huge_id", "vertex object_id"),
])
def test_bad_maps_are_one_line_naming_file_and_field_and_nothing_is_written(world, tmp_path, capsys, case, field):
    chair, _ = _parts(world)
    ply = _write(tmp_path, world, chair, np.zeros(len(chair)), {0: ("chair", 1.0)},
                 frame_world="kitchen" if case == "world" else None)
    if case == "garbage":
        ply.write_bytes(b"ply\nformat nonsense\n")
    elif case == "no_instance":
        cloud = trimesh.Trimesh(vertices=chair, faces=np.zeros((0, 3), np.int64), process=False)
        ply.write_bytes(trimesh.exchange.ply.export_ply(cloud, encoding="binary"))
    elif case == "nan":
        bad = chair.copy()
        bad[3, 1] = np.nan
        _write(tmp_path, world, bad, np.zeros(len(chair)), {0: ("chair", 1.0)})
    elif case == "label":
        ply.with_suffix(".json").write_text(json.dumps({"frame": {"world": world.name},
                                                        "objects": [{"id": 0, "label": "spaceship"}]}))
    elif case in ("confidence", "fraction"):  # a per-point confidence of 1.5; an instance id of 0.5
        cloud = trimesh.Trimesh(vertices=chair, faces=np.zeros((0, 3), np.int64), process=False)
        cloud.vertex_attributes["object_id"] = np.full(len(chair), 0.5 if case == "fraction" else 0.0, np.float32)
        cloud.vertex_attributes["confidence"] = np.full(len(chair), 1.5 if case == "confidence" else 1.0, np.float32)
        ply.write_bytes(trimesh.exchange.ply.export_ply(cloud, encoding="binary", include_attributes=True))
    elif case == "huge_id":  # an int64 id: instance x samples would overflow the scoring's pair keys
        cloud = trimesh.Trimesh(vertices=chair, faces=np.zeros((0, 3), np.int64), process=False)
        cloud.vertex_attributes["object_id"] = np.full(len(chair), 2 ** 62, np.int64)
        ply.write_bytes(trimesh.exchange.ply.export_ply(cloud, encoding="binary", include_attributes=True))
    elif case == "ascii_nan":  # trimesh would cast it to the lowest int32, warning only
        rows = "".join(f"{x} {y} {z} 0\n" for x, y, z in chair[:-1]) + "0 0 0 nan\n"
        ply.write_text(f"ply\nformat ascii 1.0\nelement vertex {len(chair)}\nproperty float x\nproperty float y\n"
                       f"property float z\nproperty int object_id\nend_header\n{rows}")
    out = tmp_path / "out"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["evaluate", "--world", str(world.path), "--map", str(ply), "--out", str(out)]) == 2
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)]  # nothing printed but the line
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(ply.stem) in err and field in err
    assert not out.exists()


def _moved(yaw_deg: float, t) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = t
    return T


def test_alignment_recovers_a_known_transform_and_a_given_one_is_applied(tmp_path, capsys):
    from rosmeery_jax.metrics.align import apply

    world = load_world("small_office")
    pts, obj = np.asarray(world.truth.samples.points, float), np.asarray(world.truth.samples.object)
    moved = _moved(4.0, [0.15, -0.10, 0.02])  # world -> the map's own frame
    objects = {n: (c, 1.0) for n, c in enumerate(world.truth.categories)}
    ply = _write(tmp_path, world, apply(moved, pts), obj, objects)
    out = tmp_path / "aligned"
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--align", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    recovered = np.asarray(summary["alignment"]["transform"])
    np.testing.assert_allclose(recovered @ moved, np.eye(4), atol=1e-3)
    assert summary["alignment"]["rms_m"] < 1e-3 and summary["ori"] == pytest.approx(1.0)
    (tmp_path / "T.json").write_text(json.dumps({"transform": np.linalg.inv(moved).tolist()}))
    given = tmp_path / "given"
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--transform", str(tmp_path / "T.json"),
                 "--out", str(given)]) == 0
    assert json.loads((given / "summary.json").read_text())["ori"] == pytest.approx(1.0)
    unaligned = tmp_path / "raw"
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(unaligned)]) == 0
    assert json.loads((unaligned / "summary.json").read_text())["ori"] < 0.5  # the test's premise
    (tmp_path / "bad.json").write_text(json.dumps({"transform": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}))
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--transform", str(tmp_path / "bad.json"),
                 "--out", str(tmp_path / "x")]) == 2
    assert "bad.json: transform: is not a rigid transform" in capsys.readouterr().err
    (tmp_path / "huge.json").write_text(json.dumps({"transform": [[1e200, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                                  [0, 0, 0, 1]]}))
    with warnings.catch_warnings(record=True) as caught:  # its R @ R.T would overflow
        warnings.simplefilter("always")
        assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--transform",
                     str(tmp_path / "huge.json"), "--out", str(tmp_path / "x")]) == 2
    assert not caught and "huge.json: transform: is not a rigid transform" in capsys.readouterr().err
