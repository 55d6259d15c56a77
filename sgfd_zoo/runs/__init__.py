"""A run's files. Read without torch (reporting and the sweep's planning use them): ``folders`` (the run folders),
``records`` (a study's records), ``checkpoints`` (their index), ``provenance`` (what trained a run), ``files`` and
``locks`` (files written whole, one writer per run). Used while training: ``checkpoint_callback`` (checkpoints a
crash cannot spoil), ``training_state`` (what an exact resume needs) and ``resuming`` (where a run starts from)."""
