"""Argument types shared by the ``cellctl`` subcommands."""

from __future__ import annotations

import argparse
from collections.abc import Callable


def whole_number(minimum: int, rule: str) -> Callable[[str], int]:
    """An argparse type: a whole number not below ``minimum`` (``rule`` says so when it is)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"{rule}, got {v}")
        return v

    return parse


positive_int = whole_number(1, "must be at least 1")
non_negative_int = whole_number(0, "must not be negative")
