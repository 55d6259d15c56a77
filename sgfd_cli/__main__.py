"""``python -m sgfd_cli``: the ``sgfd-zoo`` command."""

import sys

from sgfd_cli.commands import main

sys.exit(main())
