"""``python -m tests.zoo.stalled_run STEP MARKER ARGS...``: the sgfd-zoo command with ARGS, whose training stops
advancing once it has taken STEP agent steps: it writes MARKER and waits there to be killed.

A test that kills a run between two checkpoints uses it, so that where the kill lands does not depend on how fast
the machine trains (a sleep before the kill would let a fast machine pass the next checkpoint)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sgfd_cli import main


def stall_at(step: int, marker: Path) -> None:
    """Every off-policy agent collects no step beyond ``step``: it writes ``marker`` and sleeps until killed."""
    collect = OffPolicyAlgorithm.collect_rollouts

    def collect_until(self: OffPolicyAlgorithm, *args: Any, **kwargs: Any) -> Any:
        if self.num_timesteps >= step:
            marker.write_text(str(self.num_timesteps))
            while True:
                time.sleep(60)
        return collect(self, *args, **kwargs)

    OffPolicyAlgorithm.collect_rollouts = collect_until  # type: ignore[method-assign]


if __name__ == "__main__":
    stall_at(int(sys.argv[1]), Path(sys.argv[2]))
    sys.exit(main(sys.argv[3:]))
