"""Knowledge exchange inside a team, as one interface (docs/transfer.md): the protocol
(:class:`~dqn_transfer.exchange.base.ExchangeMethod`) and its methods, one module each, by name.

The trainer and the replicas call the run's ``transfer.exchange`` method through its hooks only; the
plan checks every method a config runs (:func:`check_exchange`), the team methods the learner is built
with included.
"""

from __future__ import annotations

from dqn_transfer.config import TrainConfig
from dqn_transfer.enums import Exchange
from dqn_transfer.exchange.advice import Advice
from dqn_transfer.exchange.base import ExchangeMethod
from dqn_transfer.exchange.best import BestCopy
from dqn_transfer.exchange.confidence import Confidence
from dqn_transfer.exchange.experience import Experience
from dqn_transfer.exchange.none import NoExchange
from dqn_transfer.exchange.sham import ShamReplay
from dqn_transfer.exchange.shared_network import SharedNetwork
from dqn_transfer.exchange.shared_replay import SharedReplay
from dqn_transfer.exchange.vdn import TeamLoss

# transfer.exchange: the method of each value.
EXCHANGES: dict[Exchange, type[ExchangeMethod]] = {
    Exchange(method.name): method
    for method in (NoExchange, BestCopy, SharedReplay, Experience, Confidence, Advice, ShamReplay)
}
# The methods the learner is built with (agent.*): checked at plan time, no hook of the loop.
TEAM_METHODS: tuple[type[ExchangeMethod], ...] = (SharedNetwork, TeamLoss)


def exchange_method(config: TrainConfig) -> type[ExchangeMethod]:
    """The class of ``config``'s ``transfer.exchange``."""
    return EXCHANGES[Exchange(config.transfer.exchange)]


def check_exchange(config: TrainConfig) -> None:
    """Refuse, in one line (``ConfigError``), what a method ``config`` runs cannot run (at plan time)."""
    for method in (exchange_method(config), *TEAM_METHODS):
        if method.asked_by(config) is not None:
            method.check(config)


__all__ = ["EXCHANGES", "TEAM_METHODS", "ExchangeMethod", "check_exchange", "exchange_method"]
