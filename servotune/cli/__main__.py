"""``python -m servotune.cli``: the command line, exactly as the ``servotune`` script runs it."""

import sys

from servotune.cli import main

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
