"""``python -m sgfd_zoo``: the command lives one floor up (it dispatches to the analysis package too), so this
names it instead of importing it (the zoo imports nothing above itself)."""

import sys

print("sgfd_zoo: the command is sgfd-zoo, or python -m sgfd_cli (e.g. python -m sgfd_cli train -h)", file=sys.stderr)
sys.exit(2)
