"""The knowledge-exchange protocol: what a method needs, when it runs and what it records.

Every way agents of a team share what they learn is an :class:`ExchangeMethod`, one module each,
registered by name in :mod:`dqn_transfer.exchange`: the ``transfer.exchange`` methods, and the team
methods the learner is built with (``agent.share_parameters``, ``agent.mixer=vdn``), whose work is in
the learner and which take part here only through :meth:`~ExchangeMethod.check`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from dqn_transfer.agents import Learner, Team, Transition
from dqn_transfer.config import ConfigError, TrainConfig, TransferConfig
from dqn_transfer.enums import Algorithm, Exchange, Mixer

LEARNERS = {
    "tabular": "a tabular learner (agent=sarsa or agent=qlearning)",
    "dqn": "a DQN learner (agent=dqn or agent=double_dqn)",
}


class ExchangeMethod:
    """One knowledge-exchange method of a run (its replicas' windows included). Every hook does nothing
    unless a method says otherwise.

    :param transfer: the run's ``transfer`` settings
    :param num_replicas: R, the replicas whose windows it keeps
    """

    name: ClassVar[str]  # as the config spells it
    family: ClassVar[str | None] = None  # the learners it works with (Algorithm.family), None: both
    needs: ClassVar[str] = ""  # what it does that needs them, for the refusal of another learner
    moves_transitions: ClassVar[bool] = False  # between the agents' replays (VDN's aligned team steps refuse it)
    fills_replays: ClassVar[bool] = False  # each agent's replay also takes its team-mates' transitions
    at_interval: ClassVar[bool] = False  # exchange() every transfer.exchange_every episodes of a replica
    in_loop: ClassVar[bool] = True  # a hook acts inside the loop (the compiled steps have none)

    def __init__(self, transfer: TransferConfig, num_replicas: int) -> None:
        self.transfer = transfer

    @classmethod
    def asked_by(cls, config: TrainConfig) -> str | None:
        """The setting of ``config`` that runs this method, as a refusal names it; None if it does not."""
        return f"transfer.exchange={cls.name}" if Exchange(config.transfer.exchange).value == cls.name else None

    # ------------------------------------------------------------------------------------------ the hooks
    @classmethod
    def check(cls, config: TrainConfig) -> None:
        """At plan time, the one moment a run's configuration is checked: refuse what the method cannot run,
        in one line (``ConfigError``). The learner family it asks for has the capabilities
        (:mod:`dqn_transfer.agents.base`) its hooks call, so the hooks do not check them again."""
        algorithm = Algorithm(config.agent.algorithm)
        if cls.family is not None and algorithm.family != cls.family:
            raise ConfigError(
                f"{cls.asked_by(config)} {cls.needs}: it needs {LEARNERS[cls.family]}, not agent={algorithm.value}"
            )
        if cls.moves_transitions and Mixer(config.agent.mixer) is Mixer.vdn:
            raise ConfigError(
                f"{cls.asked_by(config)} moves transitions between the agents' replays; agent.mixer=vdn trains on "
                "the team's aligned joint steps: use transfer.exchange=none or best"
            )

    def start(self, learner: Learner) -> None:
        """Once the learner is built, before any step (and before a resumed run loads its state)."""

    def after_step(self, transition: Transition, bounced: np.ndarray) -> None:
        """After every joint step of all replicas: ``transition`` (rows ``r * K + k``) and ``bounced``
        ``bool [R, K]``, who moved into an obstacle."""

    def exchange(self, r: int, team: Team, returns: np.ndarray) -> list[tuple[str, float]]:
        """With :attr:`at_interval`, every ``exchange_every`` episodes of replica ``r``: exchange inside its
        ``team`` given each agent's episodic ``returns [episodes, K]`` since the last time; returns the
        scalars to record."""
        return []

    def state(self, r: int) -> dict[str, np.ndarray]:
        """Replica ``r``'s window, as a checkpoint holds it (``exchange/<name>``)."""
        return {}

    def load_state(self, r: int, arrays: dict[str, Any], num_agents: int) -> None:
        """Restore what :meth:`state` returned (from a checkpoint's ``exchange/`` arrays)."""
