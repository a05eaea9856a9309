"""``python -m photax.cli``: the ``photax`` command."""

import sys

from . import main

sys.exit(main())
