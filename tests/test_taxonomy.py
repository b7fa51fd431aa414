import pytest

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.world.taxonomy import load_taxonomy


def test_builtin_taxonomy_chains_and_coco_names():
    tax = load_taxonomy()
    assert tax.chain("chair") == ("chair", "seating", "furniture")
    assert tax.chain("laptop")[2] == "accessory"
    assert tax.predicates("chair_1", "dining table") == (
        ("chair_1", "instance-of", "dining table"), ("chair_1", "is-a", "table"), ("chair_1", "is-a", "furniture"))
    for coco in ("chair", "couch", "bed", "dining table", "tv", "laptop", "book", "refrigerator", "oven",
                 "microwave", "sink", "toilet"):
        assert tax[coco].coco
    assert not tax["desk"].coco and not tax["shelf"].coco


@pytest.mark.parametrize("text, where", [
    ("[roots]\na='x'\n[macros]\nm='zzz'\n[categories.c]\nmacro='m'\n", "macros.m"),
    ("[roots]\na='x'\n[macros]\nm='a'\n[categories.c]\nmacro='q'\n", "categories.c.macro"),
    ("[roots]\na='x'\n", "[macros]"),
    ("not = [toml", "file: not valid TOML"),
])
def test_bad_taxonomy_names_file_and_field(tmp_path, text, where):
    path = tmp_path / "tax.toml"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        load_taxonomy(path)
    assert str(path) in str(err.value) and where in str(err.value)
