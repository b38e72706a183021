"""``transfer.exchange=advice`` (Torrey & Taylor 2013), tables only: from the first step, an exploring
agent that visited its state fewer than ``advice_ask_below`` times takes the greedy action of the
team-mate that visited it most (if at least ``advice_answer_from`` times), within a budget of
``advice_budget`` advised steps. It acts inside the learner's ``act``
(:mod:`dqn_transfer.agents.visit_exchange`); a resumed run loads the budgets left."""

from __future__ import annotations

from typing import cast

from dqn_transfer.agents import AdviceRules, Learner, VisitExchange
from dqn_transfer.exchange.base import ExchangeMethod


class Advice(ExchangeMethod):
    name = "advice"
    family, needs = "tabular", "works on visit counts of table entries"

    def start(self, learner: Learner) -> None:
        transfer = self.transfer
        rules = AdviceRules(transfer.advice_ask_below, transfer.advice_answer_from, transfer.advice_budget)
        cast(VisitExchange, learner).start_advice(rules)  # full budgets
