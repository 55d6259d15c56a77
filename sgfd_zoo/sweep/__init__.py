"""``sgfd-zoo sweep``: many runs as Ray tasks. ``command`` (the command: its options, the runs, the summary),
``plan`` (which runs to start, continue or leave alone; no Ray, no torch), ``ray_runs`` (the runs as Ray tasks, here
or on a cluster) and ``progress`` (the live board of their progress)."""
