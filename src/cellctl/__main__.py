"""``python -m cellctl``: the same as the ``cellctl`` command."""

import sys

from cellctl.cli import main

if __name__ == "__main__":
    sys.exit(main())
