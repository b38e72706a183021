"""What a run will need, checked before anything is allocated: the map's side, and memory.

:func:`check_size` bounds ``env.size`` (and a layout's side) at :data:`MAX_SIZE`: the ``position``
segment of an observation is one-hot over the n * n cells, the map generation's connectivity checks
cost about n^4 (0.25 s at n = 64, minutes at n = 300), the default episode is n * n steps long and a
transfer's position table is n^2 x n^2. Every shipped config and the study stay at n <= 12.

:func:`check_memory` estimates the bytes a planned run holds at its peak and refuses, in one line, a
run that would not fit in this machine's available memory (``MemAvailable`` of ``/proc/meminfo``).
Per run, with R replicas (``replicas.seeds * replicas.maps``), A agents, observation width D, 4 actions:

* DQN replay: R * A rows of ``min(buffer_size, total_steps * (A with shared_replay, else 1))``
  transitions of ``2 D + 3`` float32 (obs, next_obs, reward, action, terminated). The buffer is
  ``np.zeros``, committed as it fills, so a run that stops filling it never pays for the rest;
* DQN networks: R * (1 with share_parameters, else A) members of P parameters (layers D, hidden..., 4),
  5 float32 copies each (online, target, gradient, Adam's two moments);
* tabular: states = cells * 2^k chest flags, * (k + 1) assignments in deliberative mode. Dense tables
  when they fit in ``DENSE_TABLES_MAX_BYTES`` (256 MB): every state's row for each of the R * A agents,
  4 float32 Q-values, an int32 entry order and an int64 visit count. Else per replica an index of S
  observations, S at most ``min(2 A (total_steps + 1), states)`` (each agent meets at most one new
  observation per step, greedy evaluations as many again), held in arrays of up to 2 S rows (they grow
  by doubling): A rows of the same per state, the key (D float32), and ~150 bytes of the index's dict entry;
* the map: per replica two games (training, evaluation) of ``cells * (16 + 12 (2r + 1)^2)`` bytes, and
  with transfer the source's and the target's one-hot position tables (2 * cells^2 float32).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from dqn_transfer.agents.tabular import DENSE_TABLES_MAX_BYTES, table_bytes_per_state
from dqn_transfer.config import ConfigError, TrainConfig
from dqn_transfer.enums import Algorithm, Mode, ObsEncoding
from dqn_transfer.exchange import exchange_method

# The largest map side a run accepts (see the module docstring for why).
MAX_SIZE = 64
FLOAT = 4  # bytes of a float32
NUM_ACTIONS = 4
INDEX_ENTRY_OVERHEAD = 150  # bytes of an observation's entry in a replica's index (its bytes key, the dict slot)


def check_size(side: int, what: str = "env.size") -> None:
    """Refuse a map side above :data:`MAX_SIZE`, with the reason."""
    if side > MAX_SIZE:
        raise ConfigError(
            f"{what}={side} is above the largest map this trainer supports, {MAX_SIZE}: an observation's "
            f"position is one-hot over the {side}x{side}={side * side} cells and generating the map costs "
            "about size^4 (every shipped config uses at most 12)"
        )


@dataclass(frozen=True)
class Estimate:
    """Bytes a run holds at its peak, by part."""

    replay: int = 0
    networks: int = 0
    tables: int = 0
    maps: int = 0

    @property
    def total(self) -> int:
        return self.replay + self.networks + self.tables + self.maps

    def parts(self) -> str:
        named = {"replay": self.replay, "networks": self.networks, "Q-tables": self.tables, "maps": self.maps}
        return ", ".join(f"{name} {gigabytes(b)}" for name, b in named.items() if b >= 1e6) or "maps"


def obs_width(config: TrainConfig, size: int, num_treasures: int) -> int:
    """The observation width D the game will build (``TreasureHuntGame._build_obs_layout``)."""
    env = config.env
    width = size * size if ObsEncoding(env.obs_encoding) is ObsEncoding.onehot else 2
    width += num_treasures  # what the agent knows of each chest
    if Mode(env.mode) is Mode.deliberative:
        width += num_treasures  # its assignment
    if env.view_radius > 0:
        width += 3 * (2 * env.view_radius + 1) ** 2
    return width


def estimate(config: TrainConfig, size: int, num_agents: int, num_treasures: int) -> Estimate:
    """The memory ``config`` needs on a map of side ``size`` with these counts (module docstring)."""
    replicas = config.replicas.seeds * config.replicas.maps
    agent = config.agent
    width = obs_width(config, size, num_treasures)
    cells = size * size
    view = (2 * config.env.view_radius + 1) ** 2 if config.env.view_radius > 0 else 0
    maps = replicas * 2 * cells * (16 + 3 * FLOAT * view)
    if config.transfer.enabled:
        maps += 2 * cells * cells * FLOAT
    steps = max(config.total_steps, 0)
    if Algorithm(agent.algorithm).is_tabular:
        states = (
            cells
            * 2 ** min(num_treasures, 40)
            * (num_treasures + 1 if Mode(config.env.mode) is Mode.deliberative else 1)
        )
        per_row = table_bytes_per_state(NUM_ACTIONS)
        dense = replicas * num_agents * states * per_row
        if dense <= DENSE_TABLES_MAX_BYTES:
            return Estimate(tables=dense, maps=maps)
        seen = min(2 * num_agents * (steps + 1), states)
        per_state = num_agents * per_row + FLOAT * width + INDEX_ENTRY_OVERHEAD
        return Estimate(tables=replicas * 2 * seen * per_state, maps=maps)
    filled = min(agent.buffer_size, steps * (num_agents if exchange_method(config).fills_replays else 1))
    replay = replicas * num_agents * filled * (2 * width + 3) * FLOAT
    sizes = [width + (num_agents if agent.agent_id_input else 0), *agent.hidden, NUM_ACTIONS]
    parameters = sum(a * b + b for a, b in zip(sizes, sizes[1:]))
    members = replicas * (1 if agent.share_parameters else num_agents)
    return Estimate(replay=replay, networks=members * parameters * 5 * FLOAT, maps=maps)


def available_memory() -> int | None:
    """This machine's available memory in bytes (``MemAvailable``; else free pages), None if unknown."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, AttributeError):
        return None


def gigabytes(nbytes: int | float) -> str:
    value = nbytes / 1e9
    return f"{value:,.0f} GB" if value >= 100 else f"{value:.2g} GB"


def check_memory(config: TrainConfig, size: int, num_agents: int, num_treasures: int, what: str = "this run") -> None:
    """Refuse, in one line, a run whose estimate exceeds the available memory."""
    need = estimate(config, size, num_agents, num_treasures)
    have = available_memory()
    if have is not None and need.total > have:
        replicas = config.replicas.seeds * config.replicas.maps
        raise ConfigError(
            f"{what} would need about {gigabytes(need.total)} of memory ({need.parts()}; {replicas} "
            f"replica(s) x {num_agents} agent(s)), more than the {gigabytes(have)} this machine has available; "
            "lower agent.buffer_size, replicas.seeds / replicas.maps, env.size or total_steps"
        )
