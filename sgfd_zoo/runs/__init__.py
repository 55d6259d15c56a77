"""A run's files: its folder and its study record (``folders``, ``records``), its checkpoints and the callback that
takes them (``checkpoints``, ``checkpoint_callback``), what a resume needs and where it starts (``training_state``,
``resuming``), what trained it (``provenance``), and the file and lock primitives under all of them (``files``,
``locks``). Nothing here imports the experiment: reporting and the sweep's planning read runs without torch."""
