"""``python -m img2dmp COMMAND ...``: the same as the ``img2dmp`` command."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
