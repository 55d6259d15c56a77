"""The visual-generalisation benchmarks the field reports on, on dm_control's own tasks:

- :mod:`~sgfd_envs.benchmarks.dmcgb`: DMC-GB (Hansen & Wang 2021), ``DMCGB/<task>-v0``;
- :mod:`~sgfd_envs.benchmarks.dmcgb2`: DMC-GB2 (Almuzairee et al. 2024), ``DMCGB2/<task>-v0``;
- :mod:`~sgfd_envs.benchmarks.dcs`: the Distracting Control Suite (Stone et al. 2021), ``DCS/<task>-v0``.

Each module holds its benchmark's facts (tasks, modes, action repeats, ranges) and a distraction class that
:class:`~sgfd_envs.dmc.DMCEnv` applies to the picture only. The facts :mod:`sgfd_envs.registry` builds the ids from
are in :mod:`~sgfd_envs.benchmarks.facts`, which loads no simulator; this package imports none of its modules.
"""
