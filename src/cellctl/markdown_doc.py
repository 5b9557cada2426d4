"""The command line of the generated docs tables: print the Markdown, or write it to a file."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path


def markdown_doc_main(argv: list[str] | None, *, prog: str, description: str, render: Callable[[], str]) -> int:
    """``prog [-o FILE]``: the table ``render`` makes, to stdout or FILE (docs/ is generated this way)."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("-o", "--output", type=Path, help="write the Markdown here instead of stdout")
    args = parser.parse_args(argv)
    text = render()
    if args.output is None:
        sys.stdout.write(text)
    else:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text, encoding="utf-8")
    return 0
