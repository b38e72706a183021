"""``transfer.exchange=experience`` (SEAC's shared experience, SEQL its Q-learning variant), DQN only:
every gradient step of an agent is on a batch drawn from all its team-mates' replays, their samples
weighing ``experience_lambda`` times its own (the sampling and weights:
:mod:`dqn_transfer.agents.shared_experience`)."""

from __future__ import annotations

from dqn_transfer.agents import ExperienceSharing, Learner, require
from dqn_transfer.exchange.base import ExchangeMethod


class Experience(ExchangeMethod):
    name = "experience"
    family, needs = "dqn", "samples the team-mates' replays"
    capability = ExperienceSharing
    moves_transitions = True

    def start(self, learner: Learner) -> None:
        sharing = require(learner, ExperienceSharing, "transfer.exchange=experience")
        sharing.share_experience(self.transfer.experience_lambda)
