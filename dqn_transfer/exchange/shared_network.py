"""``agent.share_parameters`` (with ``agent.agent_id_input``), DQN only: one network for the whole team,
trained on every agent's transitions, the agents told apart by a one-hot of their index appended to
their observations (:mod:`dqn_transfer.agents.agent_id`). The learner is built with it; here is what it
refuses at plan time."""

from __future__ import annotations

from dqn_transfer.config import ConfigError, TrainConfig
from dqn_transfer.exchange.base import ExchangeMethod


class SharedNetwork(ExchangeMethod):
    name = "shared_network"
    family, needs = "dqn", "applies to a shared network"
    in_loop = False  # the learner is built with it

    @classmethod
    def asked_by(cls, config: TrainConfig) -> str | None:
        agent = config.agent
        if not (agent.share_parameters or agent.agent_id_input):
            return None
        return f"agent.{'share_parameters' if agent.share_parameters else 'agent_id_input'}=true"

    @classmethod
    def check(cls, config: TrainConfig) -> None:
        super().check(config)
        if not config.agent.share_parameters:
            raise ConfigError(
                "agent.agent_id_input=true tells the agents of a shared network apart: it needs "
                "agent.share_parameters=true"
            )
        if config.transfer.targets is not None:
            raise ConfigError(
                "transfer.targets: with agent.share_parameters=true all agents share one network, so all of "
                "them are transferred (leave targets unset)"
            )
