"""The semantic mapper's side of the benchmark: the ``Mapper`` protocol a researcher's own mapper
implements, and the built-in perceived mapper."""

from rosmeery_jax.mapping.perceived import PerceivedMapper
from rosmeery_jax.mapping.protocol import mapper_class


def mapper_for(spec: str) -> type:
    """A session's mapper entry's class: the built-in perceived mapper or a plugin."""
    return PerceivedMapper if spec == "perceived" else mapper_class(spec)
