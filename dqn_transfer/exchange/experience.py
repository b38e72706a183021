"""``transfer.exchange=experience`` (SEAC's shared experience, SEQL its Q-learning variant), DQN only:
every gradient step of an agent is on a batch drawn from all its team-mates' replays, their samples
weighing ``experience_lambda`` times its own (the sampling and weights:
:mod:`dqn_transfer.agents.shared_experience`)."""

from __future__ import annotations

from typing import cast

from dqn_transfer.agents import ExperienceSharing, Learner
from dqn_transfer.exchange.base import ExchangeMethod


class Experience(ExchangeMethod):
    name = "experience"
    family, needs = "dqn", "samples the team-mates' replays"
    moves_transitions = True

    def start(self, learner: Learner) -> None:
        cast(ExperienceSharing, learner).share_experience(self.transfer.experience_lambda)
