"""Procedural worlds: determinism, validity over many seeds, names, commands, sessions, banks."""

from __future__ import annotations

import hashlib
import json
import math
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from scipy import ndimage

from rosmeery_jax.apps.cli import main
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.specs import expand_ranges
from rosmeery_jax.world import load_world
from rosmeery_jax.world.generate import KINDS, GenerationError, GenOptions, check_options, generate
from rosmeery_jax.world.procedural import parse_name, write_world
from rosmeery_jax.world.recipes import ROOMS, room_types

# sha256 of `procedural:office:0`'s file. It changes only with the generator's VERSION: a
# change that alters files for the same options must bump VERSION and this value.
OFFICE_0_SHA256 = "719a3e7d4cba6302010410bf22700f0bea9caa18a05365c56ec7cc4fbe4380d1"


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def test_same_options_give_the_same_bytes_in_another_process():
    text = generate(GenOptions("office", 0)).xml()
    code = ("from rosmeery_jax.world.generate import generate, GenOptions;"
            "import sys; sys.stdout.write(generate(GenOptions('office', 0)).xml())")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert other == text
    assert _sha(text) == OFFICE_0_SHA256
    assert generate(GenOptions("office", 1)).xml() != text


def _max_objects(kind: str, rooms: int) -> int:
    """Up to one object per 2.5 m^2 of the smallest floor the rooms can draw."""
    return max(rooms, int(sum(ROOMS[t].area[0] for t in room_types(kind, rooms)) / 2.5))


@st.composite
def options(draw):
    kind = draw(st.sampled_from(KINDS))
    rooms = draw(st.integers(1, 6))
    objects = draw(st.integers(rooms, _max_objects(kind, rooms)))
    clutter = draw(st.floats(0.0, 0.5))
    return GenOptions(kind, draw(st.integers(0, 2 ** 31)), rooms, objects, clutter)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(options())
@example(GenOptions("lab", 642, 6, 10, 0.0))  # its first 8 draws fail (7 floor plans, 1 unviewable object)
def test_layouts_hold_what_was_asked_without_overlaps(o):
    layout = generate(o)
    assert len(layout.items) == o.objects
    assert [t for t, _ in layout.rooms] == room_types(o.kind, o.rooms)
    for i, a in enumerate(layout.items):
        assert a.rect.within(layout.rooms[a.room][1])
        for b in layout.items[i + 1:]:
            assert not (a.rect.overlaps(b.rect) and a.z < b.top and b.z < a.top), (a, b)
    for d0, d1 in layout.doors:
        assert d1 - d0 >= 90
    assert generate(o).xml() == layout.xml()


def _footprint_distance_to(mask: np.ndarray, fs, center, size) -> float:
    """Metres from an axis-aligned footprint to the nearest cell of ``mask``."""
    dist = ndimage.distance_transform_edt(~mask) * fs.resolution
    lo = np.asarray(center[:2]) - np.asarray(size[:2]) / 2
    hi = np.asarray(center[:2]) + np.asarray(size[:2]) / 2
    (i0, j0), (i1, j1) = fs.cell(lo), fs.cell(hi)
    return float(dist[max(i0, 0):i1 + 1, max(j0, 0):j1 + 1].min())


@pytest.mark.parametrize("kind", KINDS)
def test_generated_worlds_pass_the_loader_and_every_object_is_reachable_and_viewable(kind, tmp_path):
    for seed in range(3):
        layout = generate(GenOptions(kind, seed))
        world = load_world(write_world(layout, tmp_path))
        fs, t = world.free_space, world.truth
        assert t.num_objects == layout.options.resolved().objects
        assert fs.reachable[fs.cell(world.spawn[:2])]
        assert (t.ps_G > 0).all()  # every object has surface the camera can see
        turned = np.round(np.abs(np.sin(t.bbox_yaw))).astype(bool)  # quarter turns only
        sizes = np.where(turned[:, None], t.bbox_size[:, [1, 0, 2]], t.bbox_size)
        for n in range(t.num_objects):
            assert _footprint_distance_to(fs.reachable, fs, t.bbox_center[n], sizes[n]) <= 1.05, t.names[n]
        for _, r in layout.rooms:  # every room has reachable floor
            (i0, j0), (i1, j1) = fs.cell((r.x0 / 100, r.y0 / 100)), fs.cell((r.x1 / 100, r.y1 / 100))
            assert fs.reachable[i0:i1, j0:j1].sum() * fs.resolution ** 2 >= 0.25


def test_procedural_names_load_everywhere_and_ranges_expand():
    world = load_world("procedural:lab:4")
    assert world.name == "procedural_lab_4" and world.title == "Procedural Lab 4"
    assert world.path.read_text() == generate(GenOptions("lab", 4)).xml()
    small = load_world("procedural:office:2:rooms=2:objects=9")
    assert small.name == "procedural_office_2_r2_k9" and small.truth.num_objects == 9
    assert expand_ranges(["kitchen", "procedural:lab:3-5:objects=8"]) == (
        "kitchen", "procedural:lab:3:objects=8", "procedural:lab:4:objects=8", "procedural:lab:5:objects=8")


@pytest.mark.parametrize("name, where", [
    ("procedural:castle:1", "kind"), ("procedural:office:x", "seed"), ("procedural:office:-1", "seed"),
    ("procedural:office:1:floors=2", "floors"), ("procedural:office:1:rooms=two", "rooms"),
    ("procedural:office:1:rooms=0", "rooms"), ("procedural:office:1:objects=0", "objects"),
    ("procedural:office:1:objects=400", "objects"), ("procedural:office:1:clutter=2", "clutter"),
    ("procedural:office:1:tuck=-0.1", "tuck"), ("procedural:office:1:tuck=x", "tuck"),
    ("procedural:office:1:turn=200", "turn"), ("procedural:office:1:islands=1.5", "islands"),
    ("procedural:office:1:spare=-1", "spare"),
])
def test_bad_procedural_names_are_one_clear_error(name, where):
    with pytest.raises(InputError) as err:
        parse_name(name)
    assert where in str(err.value) and "\n" not in str(err.value)


def _chairs_under_tables(layout) -> list[float]:
    """For each chair, how deep its plan rect reaches under a desk or table, as a share of
    the chair's extent along that direction."""
    tables = [it.rect for it in layout.items if it.piece.category in ("desk", "dining table")]
    depths = []
    for r in (it.rect for it in layout.items if it.piece.category == "chair"):
        share = 0.0
        for t in tables:
            ox, oy = min(r.x1, t.x1) - max(r.x0, t.x0), min(r.y1, t.y1) - max(r.y0, t.y0)
            if ox > 0 and oy > 0:  # the shallower overlap is the depth pushed in
                share = max(share, ox / r.w if ox < oy else oy / r.h)
        depths.append(share)
    return depths


def test_tuck_pushes_chairs_under_their_desk_by_at_most_half_their_depth():
    assert all(d == 0 for d in _chairs_under_tables(generate(GenOptions("office", 3))))
    tucked = generate(GenOptions("office", 3, tuck=1.0))
    depths = _chairs_under_tables(tucked)
    assert depths and all(0 <= d <= 0.5 + 1e-9 for d in depths)
    assert sum(d > 0 for d in depths) >= len(depths) // 2  # a draw of 0 cm leaves a chair just touching
    assert tucked.options.name == "procedural_office_3_t1"
    assert parse_name("procedural:office:3:tuck=1") == GenOptions("office", 3, tuck=1.0)
    world = load_world("procedural:office:3:tuck=1")
    assert world.name == "procedural_office_3_t1" and world.truth.num_objects == len(tucked.items)
    assert "--tuck 1" in tucked.xml() and "--tuck" not in generate(GenOptions("office", 3)).xml()


def test_turn_leaves_chairs_askew_within_the_bound_and_nothing_else():
    askew = generate(GenOptions("office", 3, tuck=1.0, turn=30))
    assert askew.options.name == "procedural_office_3_t1_y30" and "--turn 30" in askew.xml()
    # each body's yaw off its nearest quarter turn, in degrees
    off = [math.degrees((b.pose[3] + math.pi / 4) % (math.pi / 2) - math.pi / 4) for b in askew.bodies()]
    chairs = [o for o, b in zip(off, askew.bodies()) if b.category == "chair"]
    assert chairs and all(abs(o) <= 30 + 1e-6 for o in chairs) and max(map(abs, chairs)) > 5
    assert all(abs(o) < 1e-6 for o, b in zip(off, askew.bodies()) if b.category != "chair")
    assert load_world("procedural:office:3:tuck=1:turn=30").truth.num_objects == len(askew.items)


def test_islands_set_desks_end_to_end_in_free_standing_rows_with_a_chair_and_monitor_each():
    layout = generate(GenOptions("lab", 2, islands=1.0))
    assert layout.options.name == "procedural_lab_2_i1" and "--islands 1" in layout.xml()
    desks = [it for it in layout.items if it.piece.category == "desk"]
    walls = [it for it in desks if any(abs(a - b) <= 2 for a, b in zip(it.rect, layout.rooms[it.room][1]))]
    assert len(desks) >= 2 and not walls  # no desk against a wall
    for d in desks:  # each desk touches another end to end or back to back, and has its chair
        assert any(d is not e and d.rect.overlaps(e.rect.grow(1)) and d.size == e.size for e in desks)
        assert sum(it.piece.category == "chair" and it.rect.overlaps(d.rect.grow(7)) for it in layout.items) >= 1
    screens = [it for it in layout.items if it.piece.category == "monitor"]
    assert all(any(s.z == d.top and s.rect.within(d.rect) for d in desks) for s in screens)
    assert load_world("procedural:lab:2:islands=1").truth.num_objects == len(layout.items)


def _lone_chairs(layout) -> list:
    """The chairs standing 20 cm or more from every desk and table."""
    tables = [it.rect for it in layout.items if it.piece.category in ("desk", "dining table")]
    return [it for it in layout.items if it.piece.category == "chair"
            and not any(it.rect.overlaps(t.grow(20)) for t in tables)]


def test_spare_chairs_stand_alone_with_their_backs_to_a_wall():
    plain, spare = generate(GenOptions("kitchen", 5)), generate(GenOptions("kitchen", 5, spare=1.0))
    assert spare.options.name == "procedural_kitchen_5_s1" and "--spare 1" in spare.xml()
    assert "--spare" not in plain.xml()
    alone = _lone_chairs(spare)
    assert not _lone_chairs(plain)
    assert len(alone) >= 2
    for it in alone:  # its back (+y, -x, -y, +x for k = 0..3) within a few cm of its room's wall
        x0, y0, x1, y1 = spare.rooms[it.room][1]
        gap = (y1 - it.rect.y1, it.rect.x0 - x0, it.rect.y0 - y0, x1 - it.rect.x1)[it.k]
        assert 0 <= gap <= 10, (it.rect, it.k, gap)
    assert load_world("procedural:kitchen:5:spare=1").truth.num_objects == len(spare.items)


def test_more_objects_than_fit_names_what_could_not_be_placed():
    with pytest.raises(InputError, match="do not fit"):
        check_options(GenOptions("lab", 0, rooms=1, objects=200))
    with pytest.raises(GenerationError, match="could not place .* clutter objects") as raised:
        generate(GenOptions("apartment", 0, rooms=4, objects=46))
    assert "spare" not in str(raised.value)
    # half the objects clutter, each a spare chair against a wall: the walls run out
    with pytest.raises(GenerationError, match="clutter objects .* or a lower spare"):
        generate(GenOptions("office", 0, clutter=0.5, spare=1.0))


def test_generate_command_writes_loadable_files_and_bad_input_writes_nothing(tmp_path, capsys):
    out = tmp_path / "worlds"
    assert main(["worlds", "generate", "--kind", "apartment", "--seed", "7", "--count", "3", "--out", str(out)]) == 0
    files = sorted(out.glob("*.xml"))
    assert [f.name for f in files] == [f"procedural_apartment_{s}.xml" for s in (7, 8, 9)]
    assert files[1].read_text() == generate(GenOptions("apartment", 8)).xml()
    for argv, field in [(["--kind", "castle", "--seed", "1"], "kind"),
                        (["--kind", "lab", "--seed", "1", "--objects", "900"], "objects"),
                        (["--kind", "lab", "--seed", "1", "--clutter", "1.5"], "clutter")]:
        bad = tmp_path / field
        assert main(["worlds", "generate", *argv, "--out", str(bad)]) == 2
        assert not bad.exists()
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and field in err
    assert main(["worlds", "stats", str(out), "small_office"]) == 0
    text = capsys.readouterr().out
    assert "procedural_apartment_9" in text and "small_office" in text and "4 worlds" in text


def test_a_bank_of_generated_worlds_runs_in_one_session_with_one_compile(tmp_path):
    out = tmp_path / "out"
    worlds = "procedural:office:0-1:rooms=1:objects=5"
    assert main(["run", "--worlds", worlds, "--policies", "frontier", "--seeds", "1", "--duration", "3",
                 "--detector", "off", "--quiet", "--out", str(out)]) == 0
    timing = json.loads((out / "timing.json").read_text())
    assert timing["compiles"] == 1
    runs = {p.name.split(".")[0] for p in (out / "runs").iterdir()}
    assert runs == {"procedural_office_0_r1_k5__frontier", "procedural_office_1_r1_k5__frontier"}


def test_world_bank_steps_each_world_as_that_world_alone():
    from rosmeery_jax.env import RobotEnv
    from rosmeery_jax.env.world_bank import world_bank

    bank = world_bank(["procedural:lab:0-1:rooms=1:objects=4"])
    assert len(bank) == 2 and jax.tree.leaves(bank.data)[0].shape[0] == 2

    def first_step(env, key):
        s = env.reset(key)
        return env.step(s, env.data.spawn + jnp.array([0.3, 0.0, 0.0])).pose  # drive 0.3 m ahead

    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    both = jax.jit(jax.vmap(lambda i, k: first_step(bank.env_at(i), k)))(jnp.arange(2), keys)
    alone = RobotEnv(bank.worlds[1], bank.env.config, bank.env.sizes)  # not the bank's template world
    np.testing.assert_allclose(both[1], jax.jit(lambda k: first_step(alone, k))(keys[1]), atol=1e-5)
    np.testing.assert_allclose(both[:, :2], np.stack([w.spawn[:2] for w in bank.worlds]), atol=0.05)
    assert not np.allclose(both[0], both[1])  # different spawns: each env really is in its own world
