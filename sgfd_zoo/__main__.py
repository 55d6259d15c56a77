"""``python -m sgfd_zoo``: the ``sgfd-zoo`` command."""

import sys

from sgfd_zoo.cli import main

sys.exit(main())
