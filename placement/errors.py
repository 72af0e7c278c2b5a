"""The placement package's one exception type."""

from __future__ import annotations


class PlacementError(ValueError):
    """A bad argument to the placement code: the message names the value and what is
    accepted."""
