"""The agent-id input of a shared network (``agent.agent_id_input``): a one-hot of the agent's index.

With ``agent.share_parameters`` one network serves a team, and agents that observe the same thing get
the same Q-values. Appending a one-hot of the agent's index to its observation lets the shared network
tell them apart while still learning from all of them, the usual remedy (Gupta, Egorov & Kochenderfer
2017, "Cooperative multi-agent control using deep reinforcement learning"; Terry et al. 2020,
"Revisiting parameter sharing in multi-agent deep reinforcement learning", who call it agent
indication). The one-hot is a named observation segment, ``agent_id`` (K values, last), so checkpoints
record it in ``obs_layout`` and transfer maps it by name like any segment
(:mod:`dqn_transfer.transfer.mapping`).

The game does not produce it: the learner appends it where observations enter its network (acting,
evaluation and each replay batch), so the replay stores the game's observations. A sample therefore
always carries the index of the agent whose loss it enters: a team-mate's transition copied into an
agent's replay (``transfer.exchange=shared_replay``) or drawn for its batch (``experience``) is learned
as that agent's own.
"""

from __future__ import annotations

import numpy as np

from dqn_transfer.agents.base import ObsLayout, normalize_layout

AGENT_ID = "agent_id"  # the segment's name in an observation layout


def with_agent_id(obs_layout: ObsLayout, num_agents: int) -> list[tuple[str, int]]:
    """The network's input layout: the game's segments, then ``agent_id`` (one column per agent)."""
    return [*normalize_layout(obs_layout), (AGENT_ID, num_agents)]


def agent_id_rows(num_rows: int, num_agents: int) -> np.ndarray:
    """``float32 [num_rows, K]``: row ``r * K + k`` (agent k of replica r) is the one-hot of k."""
    return np.tile(np.eye(num_agents, dtype=np.float32), (num_rows // num_agents, 1))


def append_agent_id(obs: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """``obs [rows, ..., D]`` with each row's one-hot ``ids [rows, K]`` appended to every observation."""
    shape = (*obs.shape[:-1], ids.shape[-1])
    columns = np.broadcast_to(ids.reshape(ids.shape[0], *([1] * (obs.ndim - 2)), ids.shape[-1]), shape)
    return np.concatenate([obs, columns], axis=-1)
