"""The authors' burst of updates before the first one (sb3_sgfd.common.update_burst.UpdateBurst): once, just before
SB3's first gradient step, for SB3's SAC and the EncoderSAC agents alike, and decided by what a saved model holds, so
that a resumed run takes it when, and only when, the uninterrupted run would have."""

from __future__ import annotations

import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

from sb3_sgfd import EncoderSAC
from sb3_sgfd.common.update_burst import UpdateBurst
from tests.agents.tiny import COMMON, state_env

BURST = 30
# 4 sub-envs, a rollout of 5 vector steps (20 transitions), 4 gradient steps after each: one per 5 transitions.
CADENCE = dict(COMMON, train_freq=5, gradient_steps=4)


class UpdatesAtRolloutEnds(BaseCallback):
    """The model's updates and transitions at the end of each rollout (before SB3's gradient steps after it)."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[int, int]] = []

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self.seen.append((self.model.num_timesteps, self.model._n_updates))


@pytest.mark.parametrize("algo", [SAC, EncoderSAC])
def test_the_burst_runs_once_just_before_the_first_gradient_step(algo):
    model = algo("MlpPolicy", state_env(), **CADENCE)
    seen = UpdatesAtRolloutEnds()
    model.learn(200, callback=[UpdateBurst(BURST), seen])
    # learning_starts 64: SB3's first gradient steps follow the rollout that ends at 80 transitions
    assert seen.seen[:5] == [(20, 0), (40, 0), (60, 0), (80, BURST), (100, BURST + 4)]
    assert model._n_updates == BURST + 4 * 7  # the burst, then 4 after each rollout from 80 to 200
    model.env.close()


def test_a_resumed_run_takes_the_burst_when_its_checkpoint_is_from_before_it(tmp_path):
    model = SAC("MlpPolicy", state_env(), **CADENCE)
    model.learn(60, callback=UpdateBurst(BURST))
    assert model._n_updates == 0
    model.save(tmp_path / "before")
    model.learn(40, callback=UpdateBurst(BURST), reset_num_timesteps=False)
    model.save(tmp_path / "after")
    assert model._n_updates == BURST + 4 * 2
    for saved, updates in (("before", 0), ("after", BURST + 4 * 2)):
        resumed = SAC.load(tmp_path / saved, env=state_env())
        assert resumed._n_updates == updates
        resumed.learn(40, callback=UpdateBurst(BURST), reset_num_timesteps=False)
        # from before: the burst and the gradient steps after 80 and 100; from after: 2 more rounds only
        assert resumed._n_updates == (BURST + 4 * 2 if saved == "before" else updates + 4 * 2)
        resumed.env.close()
    model.env.close()


@pytest.mark.parametrize("updates", [0, -1, 2.5, True])
def test_a_burst_of_no_positive_int_is_refused_by_name(updates):
    with pytest.raises(ValueError, match=r"updates must be a positive integer"):
        UpdateBurst(updates)
