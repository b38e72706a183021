"""``transfer.exchange=best``: every ``exchange_every`` episodes, every other agent moves its values
``exchange_tau`` of the way to the agent with the highest mean episodic return over the window (a soft
copy). A network's weights move (layers kept fixed stay as they are); a table's entries move, over every
state either table holds. Records ``team/exchange_best_agent``."""

from __future__ import annotations

from typing import cast

import numpy as np

from dqn_transfer.agents import KnowledgeExchange, Team
from dqn_transfer.config import ConfigError, TrainConfig
from dqn_transfer.exchange.base import ExchangeMethod


def exchange_best(team: Team, window_returns: np.ndarray, tau: float) -> int:
    """Soft-copy the best agent of ``window_returns [episodes, K]`` into the others; returns its index."""
    best = int(np.argmax(window_returns.mean(axis=0)))
    cast(KnowledgeExchange, team).soft_copy_best(best, tau)
    return best


class BestCopy(ExchangeMethod):
    name = "best"
    at_interval = True

    @classmethod
    def check(cls, config: TrainConfig) -> None:
        super().check(config)
        if config.agent.share_parameters:
            raise ConfigError(
                "transfer.exchange=best: with agent.share_parameters=true there is only one network to exchange"
            )

    def exchange(self, r: int, team: Team, returns: np.ndarray) -> list[tuple[str, float]]:
        return [("team/exchange_best_agent", exchange_best(team, returns, self.transfer.exchange_tau))]
