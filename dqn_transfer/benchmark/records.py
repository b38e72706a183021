"""The benchmark's results as typed records, from the sections' summaries to the document.

:mod:`~dqn_transfer.benchmark.suite` builds a :class:`Benchmark` of these; :mod:`~dqn_transfer.benchmark.tables`
writes the Markdown table from it; :meth:`Benchmark.to_json` is the JSON document. Each figure is the
median over repeats, each ratio the median of the per-repeat paired ratios; ``raw`` keeps what every
repeat measured.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from enum import Enum
from typing import Any

from dqn_transfer.config import AgentConfig

Raw = list[dict[str, Any]]  # one measurement's figures per repeat, as the measuring function reported them


@dataclass(frozen=True)
class Load:
    """The load average (1, 5, 15 min) when a section started and ended; None where the OS has none."""

    start: list[float] | None
    end: list[float] | None


@dataclass(frozen=True)
class EnvRow:
    """Section 1, one team size: random play through PettingZoo's API and through the numpy core."""

    num_agents: int
    steps: int
    pettingzoo_steps_per_s: float
    core_steps_per_s: float
    core_over_pettingzoo: float
    raw: Raw


@dataclass(frozen=True)
class Contender:
    """Section 2, one trainer's figures at one thread count."""

    steps_per_s: float
    steps_per_cpu_s: float
    greedy_success: float  # mean over repeats
    greedy_return: float


@dataclass(frozen=True)
class TrainingRow:
    """Section 2, one torch thread count: our trainer against SB3's."""

    torch_threads: int
    steps: int
    ours: Contender
    sb3: Contender
    ours_over_sb3: float
    ours_over_sb3_cpu: float
    raw: dict[str, Raw]  # "ours", "sb3"


@dataclass(frozen=True)
class StepCost:
    """Section 3, one learner layout's ms per joint step: wall and CPU, and per repeat."""

    ms_per_step: float
    ms_per_agent_step: float
    cpu_ms_per_step: float
    raw_ms: list[float]
    raw_cpu_ms: list[float]


@dataclass(frozen=True)
class TeamRow:
    """Section 3, one team size K: one batched learner against K separate ones."""

    num_agents: int
    steps: int
    batched: StepCost
    separate: StepCost
    separate_over_batched: float
    separate_over_batched_cpu: float
    batched_over_k1: float
    batched_over_k1_cpu: float


@dataclass(frozen=True)
class UpdateTiming:
    """Section 4, one kind of update: us per update, and against the bare PyTorch update."""

    wall_us: float
    cpu_us: float
    over_bare: float
    over_bare_cpu: float
    raw_us: list[float]
    raw_cpu_us: list[float]


@dataclass(frozen=True)
class UpdateSection:
    updates: int
    threads: int
    default_threads: int
    timings: dict[str, UpdateTiming]  # update name (``<name>_default_threads`` at torch's default threads)


@dataclass(frozen=True)
class ProcessFigures:
    """Sections 5 and 6, one program's whole processes: medians over repeats."""

    seconds: float
    cpu_seconds: float
    steps_per_s: float  # section 6: learner-steps
    steps_per_cpu_s: float
    max_rss_mb: float
    gradient_steps: int


@dataclass(frozen=True)
class LoneContender:
    figures: ProcessFigures
    ours_over_this: float  # ours' rate over this one's, paired by repeat (> 1: ours is faster)
    ours_over_this_cpu: float
    raw: Raw


@dataclass(frozen=True)
class LoneSection:
    """Section 5: one DQN learner's whole process, ours against SB3 and bare PyTorch."""

    steps: int
    map: dict[str, Any]
    hyperparameters: AgentConfig
    contenders: dict[str, LoneContender]  # LONE_CONTENDERS
    load: Load


@dataclass(frozen=True)
class ReplicaRow:
    """Section 6, one engine and replica count R: one process of R teams."""

    engine: str
    replicas: int
    learners: int
    figures: ProcessFigures  # learner-steps
    ours_over_sb3: float
    ours_over_sb3_cpu: float
    raw: Raw


@dataclass(frozen=True)
class ReplicasSection:
    """Section 6: sweep throughput, ours one process of R replicas against one SB3 process per core."""

    steps: int
    learning_starts: int
    team_agents: int
    map: dict[str, Any]
    hyperparameters: AgentConfig
    ours_threads: int
    sb3_processes: int
    sb3: ProcessFigures  # learner-steps of the processes side by side
    sb3_raw: Raw
    rows: list[ReplicaRow]
    load: Load


@dataclass(frozen=True)
class MarginalFigures:
    """Section 7, one checkout's pairs of processes: medians over repeats of the marginal cost."""

    seconds_per_1k_steps: float
    cpu_seconds_per_1k_steps: float
    agent_steps_per_s: float
    max_rss_mb: float


@dataclass(frozen=True)
class TabularRow:
    """Section 7, one mode and replica count R: one process of R replicas of the SARSA team."""

    mode: str
    replicas: int
    ours: MarginalFigures
    baseline: MarginalFigures | None  # None: no --baseline
    speedup: float | None  # the baseline's wall seconds per step over ours', paired by repeat (> 1: ours faster)
    speedup_cpu: float | None
    raw: dict[str, Raw]  # "ours" and "baseline"


@dataclass(frozen=True)
class TabularSection:
    """Section 7: the study's tabular jobs, this checkout against an earlier one (``--baseline``)."""

    env: str
    agents: int
    steps: list[int]  # total_steps of the short and the long process
    eval_every: int
    baseline: str | None  # the baseline checkout's directory
    baseline_commit: str | None  # its git commit, where git knows it
    rows: list[TabularRow]
    load: Load


@dataclass(frozen=True)
class Machine:
    cpu_model: str
    cpu_count: int | None
    cpus_available: int
    platform: str
    python: str
    torch: str
    numpy: str
    gymnasium: str | None
    pettingzoo: str | None
    stable_baselines3: str | None
    torch_default_threads: int
    torch_threads_used: list[int]
    load: Load


@dataclass(frozen=True)
class Settings:
    profile: str
    seed: int
    repeats: int
    threads: int
    train_threads: list[int]
    sections: list[str]
    sizes: Any  # suite.Sizes
    hyperparameters: AgentConfig
    team_learning_starts: int
    env_map: dict[str, Any]
    source_map: dict[str, Any]


@dataclass(frozen=True)
class Benchmark:
    """Everything one run of the benchmark measured; a section not measured is None."""

    settings: Settings
    machine: Machine
    method: str
    env: list[EnvRow] | None = None
    training: list[TrainingRow] | None = None
    team: list[TeamRow] | None = None
    update: UpdateSection | None = None
    lone: LoneSection | None = None
    replicas: ReplicasSection | None = None
    tabular: TabularSection | None = None

    def to_json(self) -> dict[str, Any]:
        """The document: plain JSON types throughout (enums by value, tuples as lists), unmeasured sections left out."""
        document = {k: v for k, v in dataclasses.asdict(self).items() if v is not None}
        return json.loads(json.dumps(document, default=_plain))


def _plain(value: Any) -> Any:
    if isinstance(value, Enum):
        return value.value
    raise TypeError(f"{type(value).__name__} is not JSON")
