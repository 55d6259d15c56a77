"""The ``sgfd-zoo`` command: the top floor, above the zoo (:mod:`sgfd_zoo`) and the paper's analysis
(:mod:`sgfd_analysis`), whose commands it dispatches to. ``python -m sgfd_cli`` runs the same command."""

from sgfd_cli.commands import COMMANDS, main

__all__ = ["COMMANDS", "main"]
