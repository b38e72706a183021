"""``transfer.exchange=none``: every agent learns on its own."""

from __future__ import annotations

from dqn_transfer.exchange.base import ExchangeMethod


class NoExchange(ExchangeMethod):
    name = "none"
    in_loop = False
