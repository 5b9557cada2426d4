"""``python -m cellctl.plc``: print the register map as Markdown, write it, or check a file is current."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cellctl.plc.register_doc import render_markdown


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m cellctl.plc",
                                     description="Render the PLC register map as Markdown.")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--write", metavar="PATH", help="write the Markdown to PATH")
    group.add_argument("--check", metavar="PATH", help="exit 1 if PATH differs from the generated text")
    args = parser.parse_args(argv)
    text = render_markdown()
    if args.write:
        Path(args.write).write_text(text, encoding="utf-8")
    elif args.check:
        path = Path(args.check)
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            print(f"{path} is missing or stale; regenerate it with python -m cellctl.plc --write {path}",
                  file=sys.stderr)
            return 1
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
