"""The team exchanges that read visit counts (``transfer.exchange=confidence|advice``, tables only).

``confidence`` merges values once every ``exchange_every`` episodes, like the other exchanges
(:mod:`dqn_transfer.transfer.exchange`); ``advice`` acts at every exploring step, inside the learner's
``act``, once the run has switched it on. The rules are in :mod:`dqn_transfer.agents.visit_exchange`.
"""

from __future__ import annotations

from dqn_transfer.agents import AdviceRules, Team, VisitExchange, require
from dqn_transfer.config import TransferConfig
from dqn_transfer.enums import Exchange


def exchange_confidence(team: Team, weight: float) -> None:
    """Every agent merges its most-visiting team-mate's values where that team-mate visited a state more."""
    require(team, VisitExchange, "transfer.exchange=confidence").merge_confident(weight)


def start_advice(learner: Team, transfer: TransferConfig) -> None:
    """Switch advice on for every agent of ``learner`` (all its replicas), with full budgets."""
    rules = AdviceRules(transfer.advice_ask_below, transfer.advice_answer_from, transfer.advice_budget)
    require(learner, VisitExchange, f"transfer.exchange={Exchange.advice.value}").start_advice(rules)
