"""What a run's transfer configuration needs of its learner, checked when the run is built.

A learner that lacks a capability the configuration asks for (:mod:`dqn_transfer.agents.base`) is
refused with a ``ConfigError`` naming the key, before any step is taken, not in the middle of the loop.
"""

from __future__ import annotations

from dqn_transfer.agents import ExperienceSharing, KnowledgeExchange, Team, VisitExchange, WarmStart, require
from dqn_transfer.config import TrainConfig
from dqn_transfer.enums import Exchange


def needed_capabilities(config: TrainConfig, warm_start: bool) -> list[tuple[type, str]]:
    """``(capability, the setting that needs it)`` for this run; ``warm_start``: whether the run starts
    its agents from a transfer source (a source task's own run does not)."""
    transfer = config.transfer
    needed: list[tuple[type, str]] = []
    exchange = Exchange(transfer.exchange)
    if exchange is Exchange.experience:
        needed.append((ExperienceSharing, "transfer.exchange=experience"))
    elif exchange is not Exchange.none:
        needed.append((KnowledgeExchange, f"transfer.exchange={exchange.value}"))
    if exchange.reads_visits:
        needed.append((VisitExchange, f"transfer.exchange={exchange.value}"))
    if warm_start and transfer.freeze:
        needed.append((WarmStart, f"transfer.freeze={list(transfer.freeze)}"))
    if warm_start and not transfer.reset_optimizer:
        needed.append((WarmStart, "transfer.reset_optimizer=false (an optimizer state to carry over)"))
    return needed


def check_capabilities(config: TrainConfig, learner: Team, warm_start: bool) -> None:
    """Raise ``ConfigError`` if ``learner`` lacks a capability :func:`needed_capabilities` lists."""
    for capability, needed_by in needed_capabilities(config, warm_start):
        require(learner, capability, needed_by)
