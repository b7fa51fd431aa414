"""The semantic mapper's side of the benchmark: the ``Mapper`` protocol a researcher's own mapper
implements, and the built-in perceived mapper."""
