"""A burst of gradient steps before the first one of an off-policy run, which SB3 does not take.

The SGFD authors' ``train.py`` (SiliHuang-ai/SGFD; SAC-AE's, DBC's and AMBS's loops the same) collects
``init_steps`` = 1000 transitions with random actions, then, at step 1000, runs 1000 updates at once, then one
update every 5 steps (``step % 5 == 0``): about 200,800 updates in 1e6 steps. SB3 starts its gradient steps once
``learning_starts`` transitions are in the buffer, at its ``train_freq`` cadence, with no burst.
:class:`UpdateBurst` adds it to any SB3 off-policy algorithm (SB3's SAC, every EncoderSAC agent): ``updates``
gradient steps at once, just before the run's first one.
"""

from __future__ import annotations

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

from sb3_sgfd.common.validation import check_positive_int

#: The authors' burst: their ``init_steps``.
AUTHORS_BURST = 1000


class UpdateBurst(BaseCallback):
    """``updates`` gradient steps at once at the end of the first rollout after which the model trains (its
    collected transitions past ``learning_starts``), before SB3's own first gradient step.

    It decides from what the model saves: the burst is due while the model has taken no gradient step (SB3's
    ``_n_updates`` is 0), so a run resumed from a checkpoint taken before the burst takes it, one resumed after it
    does not, and a resumed run continues as the uninterrupted one would.

    :param updates: gradient steps in the burst (the authors': :data:`AUTHORS_BURST`)
    :param verbose: 1 prints a line when the burst runs
    """

    def __init__(self, updates: int = AUTHORS_BURST, verbose: int = 0) -> None:
        super().__init__(verbose)
        check_positive_int(updates=updates)
        self.updates = int(updates)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        model: BaseAlgorithm = self.model
        learning_starts = model.learning_starts  # type: ignore[attr-defined]
        if getattr(model, "_n_updates", None) != 0 or not model.num_timesteps > learning_starts:
            return
        if self.verbose:
            print(f"UpdateBurst: {self.updates} gradient steps at {model.num_timesteps} transitions")
        model.train(gradient_steps=self.updates, batch_size=model.batch_size)  # type: ignore[attr-defined]
