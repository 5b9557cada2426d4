"""Errors of the alignment step."""

from __future__ import annotations


class AlignmentError(ValueError):
    """The alignment inputs or results cannot be used; the message says which and what to do."""


class WallFitScatter(AlignmentError):
    """The wall's readings scatter about their plane by more than the limit."""
