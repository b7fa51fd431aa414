"""Worlds and ground truth (SK-GP): counts, samples on surfaces, exclusions, bad input."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

from conftest import room_xml
from rosmeery_jax.apps.cli import main
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.world.taxonomy import load_taxonomy
from rosmeery_jax.world import PAPER_WORLDS, WALL, WorldConfig, load_world

PAPER_COUNTS = {"kitchen": 35, "laboratory": 21, "small_office": 11, "large_office": 41}


def test_worlds_json_reports_paper_counts(capsys):
    assert main(["worlds", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert {n: rows[n]["objects"] for n in PAPER_WORLDS} == PAPER_COUNTS
    for r in rows.values():
        assert r["samples"] > 1000 and r["reachable_area_m2"] > 5


@pytest.mark.parametrize("name", PAPER_WORLDS)
def test_paper_world_ground_truth_is_consistent(name):
    w = load_world(name)
    t, scene = w.truth, w.scene
    tax = load_taxonomy()
    assert all(c in tax for c in t.categories)
    assert np.all(t.num_predicates == 3)
    for n, preds in enumerate(t.predicates):
        assert preds[0] == (t.names[n], "instance-of", t.categories[n])
        assert preds[1][2] == t.macros[n] and preds[2][2] == t.roots[n]
    assert np.all(t.ps_G > 0) and t.ps_G.sum() == len(t.samples.points)
    # The spawn is reachable and the reachable area lies inside the walls.
    fs = w.free_space
    assert fs.reachable[fs.cell(w.spawn[:2])]
    assert not (fs.reachable & ~fs.interior).any()
    # Every box is z-rotated only and every object has boxes; walls exist.
    assert (scene.object_id == WALL).any()
    assert set(np.unique(scene.object_id[scene.object_id >= 0])) == set(range(t.num_objects))


def _surface_distance(scene, s):
    """Distance of each sample to the surface of its own box."""
    local = scene.to_local(s.points.astype(np.float64))[np.arange(len(s.points)), s.box]
    half = scene.half[s.box]
    outside = np.linalg.norm(np.maximum(np.abs(local) - half, 0), axis=1)
    inside_depth = np.min(half - np.abs(local), axis=1).clip(min=0)
    return outside + inside_depth


@pytest.mark.parametrize("name", PAPER_WORLDS)
def test_samples_lie_on_their_object_and_in_no_other_solid(name):
    w = load_world(name)
    s, scene = w.truth.samples, w.scene
    assert _surface_distance(scene, s).max() < 1e-3
    assert np.all(scene.object_id[s.box] == s.object)
    inside = scene.inside(s.points.astype(np.float64), margin=1e-3)
    inside[np.arange(len(s.box)), s.box] = False
    assert not inside.any()
    assert s.points[:, 2].min() > -1e-6


def test_box_on_floor_has_no_bottom_samples_and_wall_face_is_excluded(write_world):
    # A 1 x 0.6 x 0.4 box on the floor, its +x face flush against the east wall.
    body = '<body name="crate"><geom type="box" pos="1.5 0 0.2" size="0.5 0.3 0.2"/></body>'
    w = load_world(write_world(room_xml(body, {"crate": "boxes"})), WorldConfig(camera_height=None))
    n = w.truth.samples.normals
    assert not (n[:, 2] < -0.5).any(), "bottom face rests on the floor"
    assert not (n[:, 0] > 0.5).any(), "the +x face touches the wall"
    assert (n[:, 2] > 0.5).any() and (n[:, 0] < -0.5).any()


def test_ps_G_scales_with_area_as_the_density_says(write_world):
    # A floating box (no contact anywhere), every face observable.
    body = '<body name="b"><geom type="box" pos="0.8 0.8 1.2" size="0.25 0.2 0.1"/></body>'
    path = write_world(room_xml(body, {"b": "boxes"}))
    area = 2 * (0.5 * 0.4 + 0.5 * 0.2 + 0.4 * 0.2)
    for density in (100.0, 400.0, 1600.0):
        ps = int(load_world(path, WorldConfig(density=density, camera_height=None)).truth.ps_G[0])
        assert abs(ps - area * density) <= 0.08 * area * density + 6, (density, ps)


def test_camera_height_removes_faces_only_seen_edge_on(write_world):
    body = ('<body name="shelf"><geom type="box" pos="1 1 1" size="0.3 0.2 1"/></body>'
            '<body name="stool"><geom type="box" pos="-1 -1 0.35" size="0.2 0.2 0.05"/></body>')
    path = write_world(room_xml(body, {"shelf": "shelf", "stool": "bench"}))
    w = load_world(path, WorldConfig(camera_height=0.5))
    s = w.truth.samples
    top_of_shelf = (s.object == 0) & (s.normals[:, 2] > 0.5)
    under_stool = (s.object == 1) & (s.normals[:, 2] < -0.5)
    assert not top_of_shelf.any() and not under_stool.any()
    w_all = load_world(path, WorldConfig(camera_height=None))
    s2 = w_all.truth.samples
    assert ((s2.object == 0) & (s2.normals[:, 2] > 0.5)).any()
    assert ((s2.object == 1) & (s2.normals[:, 2] < -0.5)).any()


def test_user_world_loads_with_nested_bodies_and_yawed_boxes(write_world):
    body = """<body name="table" pos="0.8 -0.5 0" euler="0 0 0.6">
                <geom type="box" pos="0 0 0.72" size="0.6 0.4 0.02" rgba="0.8 0.6 0.3 1"/>
                <body name="table_legs"><geom type="box" pos="0.5 0.3 0.35" size="0.03 0.03 0.35"/></body>
              </body>"""
    w = load_world(write_world(room_xml(body, {"table": "dining table"})))
    assert w.truth.names == ("table",) and w.truth.categories == ("dining table",)
    assert abs(float(w.truth.pose[0, 3]) - 0.6) < 1e-5
    assert np.all(w.scene.object_id[w.scene.object_id >= 0] == 0) and (w.scene.object_id == 0).sum() == 2
    np.testing.assert_allclose(w.truth.bbox_size[0], [1.2, 0.8, 0.74], atol=1e-4)


BAD_INPUTS = {
    "malformed": ("<mujoco><worldbody><geom type='box' size='1'/><bad/></worldbody>", "invalid MJCF"),
    "no category": (room_xml('<body name="thing"><geom type="box" pos="1 1 0.2" size="0.2 0.2 0.2"/></body>', {}),
                    "body 'thing': has no category"),
    "unknown category": (room_xml('<body name="thing"><geom type="box" pos="1 1 0.2" size="0.2 0.2 0.2"/></body>',
                                  {"thing": "spaceship"}), "body 'thing': unknown category 'spaceship'"),
    "outside walls": (room_xml('<body name="thing"><geom type="box" pos="5 5 0.2" size="0.2 0.2 0.2"/></body>',
                               {"thing": "chair"}), "body 'thing': lies outside the walls"),
    "spawn in obstacle": (room_xml('<body name="thing"><geom type="box" pos="0 0 0.2" size="0.3 0.3 0.2"/></body>',
                                   {"thing": "chair"}), "spawn (0.00, 0.00) is inside an obstacle"),
    "cylinder": (room_xml('<body name="thing"><geom type="cylinder" pos="1 1 0.2" size="0.2 0.2"/></body>',
                          {"thing": "chair"}), "geom"),
    "nan spawn": (room_xml('<body name="thing"><geom type="box" pos="1 1 0.2" size="0.2 0.2 0.2"/></body>',
                           {"thing": "chair"}, spawn=("nan", 0, 0)), "numeric 'rosmeery:spawn': [nan"),
    "nan position": (room_xml('<body name="thing"><geom name="top" type="box" pos="1 1 nan" size="0.2 0.2 0.2"/></body>',
                              {"thing": "chair"}), "geom 'top': position or size beyond"),
    "huge spawn": (room_xml('<body name="thing"><geom type="box" pos="1 1 0.2" size="0.2 0.2 0.2"/></body>',
                            {"thing": "chair"}, spawn=(1e30, 0, 0)), "must be finite numbers within"),
    "huge box": (room_xml('<body name="thing"><geom name="top" type="box" pos="1 1 0.2" size="1e30 0.2 0.2"/></body>',
                          {"thing": "chair"}), "geom 'top': position or size beyond"),
    "no walls": (room_xml('<body name="thing"><geom type="box" pos="1 1 0.2" size="0.2 0.2 0.2"/></body>',
                          {"thing": "chair"}, walls=False), "worldbody: has no walls enclosing the spawn"),
    "floating": (room_xml('<body name="thing"><geom type="box" pos="1 1 100" size="0.2 0.2 0.2"/></body>',
                          {"thing": "chair"}), "body 'thing': floats at z = 99.80 m"),
    "no spawn": (room_xml('<body name="thing"><geom type="box" pos="1 1 0.2" size="0.2 0.2 0.2"/></body>',
                          {"thing": "chair"}).replace('<numeric name="rosmeery:spawn" data="0.0 0.0 0.0"/>', ""),
                 "missing <numeric name=\"rosmeery:spawn\""),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_world_gives_one_clear_line_naming_file_and_element(case, write_world, capsys, tmp_path, monkeypatch):
    xml, expected = BAD_INPUTS[case]
    path = write_world(xml, name=case.replace(" ", "_"))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError) as err:
        load_world(path)
    assert str(path) in str(err.value) and expected in str(err.value) and "\n" not in str(err.value)
    assert main(["world", "show", str(path), "--out", str(tmp_path / "x.png")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and expected in lines[0]
    # MuJoCo's own warning handler (a NaN in the XML) would append to MUJOCO_LOG.TXT here
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists() and mujoco.get_mju_user_warning() is None


def test_latin1_world_file_is_one_line(tmp_path):
    path = tmp_path / "latin.xml"
    body = '<body name="th\u00e9"><geom type="box" pos="1 1 0.2" size="0.2 0.2 0.2"/></body>'
    path.write_bytes(room_xml(body, {"th\u00e9": "chair"}).encode("latin-1"))
    with pytest.raises(InputError, match="latin.xml: file: not UTF-8"):
        load_world(path)


def test_missing_world_file_and_unknown_name(tmp_path):
    with pytest.raises(InputError, match="world file not found"):
        load_world(tmp_path / "nope.xml")
    with pytest.raises(InputError, match="no built-in world"):
        load_world("atlantis")
    (tmp_path / "d.xml").mkdir()
    with pytest.raises(InputError, match="d.xml: is a folder, not a world file"):  # was "not found"
        load_world(tmp_path / "d.xml")


def test_a_name_or_config_of_another_type_is_a_type_error_naming_it():
    from rosmeery_jax.env import EnvConfig, world_bank

    with pytest.raises(TypeError, match=r"names must be a list of worlds \(one world: \['kitchen'\]\)"):
        world_bank("kitchen")  # its letters were read as the worlds 'k', 'i', ...
    with pytest.raises(TypeError, match="config must be an EnvConfig, not str"):
        world_bank(["kitchen"], "x")
    with pytest.raises(TypeError, match="config must be a WorldConfig, not int"):
        load_world("kitchen", 3)
    assert world_bank(("kitchen",), EnvConfig()).worlds[0].name == "kitchen"


def test_world_show_writes_a_png(tmp_path, capsys):
    out = tmp_path / "small.png"
    assert main(["world", "show", "small_office", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_world_arrays_are_read_only():
    w = load_world("small_office")
    with pytest.raises(ValueError):
        w.truth.ps_G[0] = 0
    with pytest.raises(ValueError):
        w.scene.center[0, 0] = 1.0
