"""``python -m photax.cli``: the ``photax`` command."""

import sys

from . import main

if __name__ == "__main__":
    sys.exit(main())
