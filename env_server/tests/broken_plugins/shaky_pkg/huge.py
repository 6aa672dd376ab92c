"""A module whose import fails with a 10000-character message."""

raise ImportError("x" * 10000)
