"""``transfer.exchange=confidence`` (Tan 1993), tables only: every ``exchange_every`` episodes, every
agent merges its most-visiting team-mate's values on the states that team-mate visited more, weighted
by ``confidence_weight`` and the share of the visits (the rule: :mod:`dqn_transfer.agents.visit_exchange`)."""

from __future__ import annotations

from typing import cast

import numpy as np

from dqn_transfer.agents import Team, VisitExchange
from dqn_transfer.exchange.base import ExchangeMethod


class Confidence(ExchangeMethod):
    name = "confidence"
    family, needs = "tabular", "works on visit counts of table entries"
    at_interval = True

    def exchange(self, r: int, team: Team, returns: np.ndarray) -> list[tuple[str, float]]:
        cast(VisitExchange, team).merge_confident(self.transfer.confidence_weight)
        return []
