"""RL-Zoo style training, evaluation and reporting for SGFD (the ``sgfd-zoo`` command)."""
