"""The mapping package's one exception type."""

from __future__ import annotations


class MappingError(ValueError):
    """A bad argument to the mapping code: the message names the value and what is
    accepted."""
