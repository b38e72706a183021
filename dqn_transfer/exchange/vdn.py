"""``agent.mixer=vdn`` (Sunehag et al. 2018), DQN only: the team trained on one TD error, ``Q_tot`` the
sum of the live agents' Q-values, on the sum of their rewards, from the aligned joint steps of a joint
replay. The loss is where the learner computes it (:mod:`dqn_transfer.agents.dqn_update`); here is what
it refuses at plan time: agents each after their own return (competitive mode), agents given the team's
reward already (an exchange that moves transitions between the agents' replays refuses it:
:class:`~dqn_transfer.exchange.base.ExchangeMethod`)."""

from __future__ import annotations

from dqn_transfer.config import ConfigError, TrainConfig
from dqn_transfer.enums import Mixer, Mode, RewardMode
from dqn_transfer.exchange.base import ExchangeMethod


class TeamLoss(ExchangeMethod):
    name = "vdn"
    family, needs = "dqn", "sums the agents' Q-networks"
    in_loop = False  # the learner's loss (the compiled steps leave a joint replay to Python)

    @classmethod
    def asked_by(cls, config: TrainConfig) -> str | None:
        return "agent.mixer=vdn" if Mixer(config.agent.mixer) is Mixer.vdn else None

    @classmethod
    def check(cls, config: TrainConfig) -> None:
        super().check(config)
        env = config.env
        if env.factory is None and Mode(env.mode) is Mode.competitive:  # the treasure hunt's own keys
            raise ConfigError(
                "agent.mixer=vdn trains the team on the sum of its rewards, a cooperative objective: use "
                "mode=cooperative or mode=deliberative, not mode=competitive (each agent after its own return)"
            )
        if env.factory is None and RewardMode(env.reward_mode) is not RewardMode.individual:
            raise ConfigError(
                "agent.mixer=vdn sums the agents' own rewards; env.reward_mode=team already gives each the sum, "
                "which VDN would count once per agent: use env.reward_mode=individual"
            )
