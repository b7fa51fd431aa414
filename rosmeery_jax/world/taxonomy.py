"""The object taxonomy: category -> macro-category -> root, and the predicates it implies.

The data lives in ``rosmeery_jax/world/taxonomy.toml`` (documented there). A user may pass
their own file of the same form. Predicates are triples ``(subject, relation, object)``;
for a ground-truth object ``n`` of category ``c``:

    (n, "instance-of", c), (n, "is-a", macro(c)), (n, "is-a", root(c))
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

from rosmeery_jax.core.config import read_toml
from rosmeery_jax.core.errors import InputError

DEFAULT_TAXONOMY = Path(__file__).parent / "taxonomy.toml"

Predicate = tuple[str, str, str]


@dataclass(frozen=True)
class Category:
    name: str
    macro: str
    root: str
    coco: bool
    color: tuple[float, float, float]


@dataclass(frozen=True)
class Taxonomy:
    """Immutable taxonomy. ``categories`` maps name -> :class:`Category` in file order."""

    source: str
    categories: Mapping[str, Category]

    def __hash__(self) -> int:  # the mapping proxy is not hashable; its items are
        return hash((self.source, tuple(self.categories.items())))

    def __deepcopy__(self, memo) -> "Taxonomy":  # immutable: a copy is itself (a mapping proxy cannot be copied)
        return self

    @property
    def names(self) -> tuple[str, ...]:
        """Category names in file order; index = class id used by the detector."""
        return tuple(self.categories)

    def __contains__(self, name: str) -> bool:
        return name in self.categories

    def __getitem__(self, name: str) -> Category:
        return self.categories[name]

    def index(self, name: str) -> int:
        return self.names.index(name)

    def chain(self, name: str) -> tuple[str, str, str]:
        """(category, macro, root) for a category name."""
        c = self.categories[name]
        return (c.name, c.macro, c.root)

    def predicates(self, subject: str, category: str) -> tuple[Predicate, ...]:
        """The predicates an agent declares about ``subject`` when it labels it ``category``."""
        c = self.categories[category]
        return (
            (subject, "instance-of", c.name),
            (subject, "is-a", c.macro),
            (subject, "is-a", c.root),
        )


def load_taxonomy(path: str | Path | None = None) -> Taxonomy:
    """Load and validate a taxonomy file (default: the built-in one)."""
    return _load(str(Path(path) if path is not None else DEFAULT_TAXONOMY))


@lru_cache(maxsize=8)
def _load(path: str) -> Taxonomy:
    raw = read_toml(path)
    roots = raw.get("roots")
    macros = raw.get("macros")
    cats = raw.get("categories")
    for key, value in (("roots", roots), ("macros", macros), ("categories", cats)):
        if not isinstance(value, dict) or not value:
            raise InputError(path, f"[{key}]", "missing or empty table")
    for macro, root in macros.items():
        if root not in roots:
            raise InputError(path, f"macros.{macro}", f"root {root!r} is not in [roots]")
    out: dict[str, Category] = {}
    for name, entry in cats.items():
        where = f"categories.{name}"
        if not isinstance(entry, dict) or "macro" not in entry:
            raise InputError(path, where, "needs a 'macro' field")
        macro = entry["macro"]
        if macro not in macros:
            raise InputError(path, f"{where}.macro", f"{macro!r} is not in [macros]")
        color = tuple(float(v) for v in entry.get("color", (0.6, 0.6, 0.6)))
        if len(color) != 3 or not all(0.0 <= v <= 1.0 for v in color):
            raise InputError(path, f"{where}.color", "needs three values in [0, 1]")
        out[name] = Category(name, macro, macros[macro], bool(entry.get("coco", False)), color)
    return Taxonomy(path, MappingProxyType(out))
