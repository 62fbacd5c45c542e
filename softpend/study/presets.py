"""The one home of the study's defaults and budgets: the book's profiles, the benchmarks and the commands
read them from here."""

from __future__ import annotations

#: Training episodes of each RL method: the ``softpend train`` default, the book's full profile and the
#: benchmark runs.
RL_EPISODES = {"dqn": 100, "mbpo": 50}
