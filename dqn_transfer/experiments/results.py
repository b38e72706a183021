"""What each report section found, as data: its comparisons, estimates, verdict and the settings it was run with.

:mod:`~dqn_transfer.experiments.claims` computes one of these per question from the raw data;
:mod:`~dqn_transfer.experiments.render` writes Markdown and figures from them. Nothing here is text
to be shown, except the question and its primary comparison, which the verdict rules fix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dqn_transfer.analysis.stats import Estimate, Values, mean_intervals
from dqn_transfer.analysis.transfer_metrics import Curve
from dqn_transfer.experiments.settings import Evidence, Game

SUPPORTED, NOT_SUPPORTED, CONTRADICTED, INCONCLUSIVE = "SUPPORTED", "NOT SUPPORTED", "CONTRADICTED", "INCONCLUSIVE"
EXPLORATORY = "EXPLORATORY"  # a section without a rule


@dataclass(frozen=True)
class Intervals:
    """A paired difference's mean with its t, BCa and percentile 95% intervals."""

    t: Estimate
    bca: Estimate
    percentile: Estimate

    @classmethod
    def of(cls, values: Values, rng: np.random.Generator) -> Intervals:
        found = mean_intervals(values, rng)
        return cls(found["t"], found["bca"], found["percentile"])


@dataclass(frozen=True)
class Primary:
    """A question and its one primary comparison (fixed by the verdict rules), with the verdict."""

    question: str
    comparison: str
    verdict: str


@dataclass(frozen=True)
class Series:
    """One condition's learning curves in a figure panel."""

    label: str
    condition: str  # what its colour is keyed by
    curves: list[Curve]


@dataclass(frozen=True)
class Panel:
    metric: str
    series: list[Series]


# ------------------------------------------------------------------------------------ main hypothesis


@dataclass(frozen=True)
class ExchangeRow:
    learner: str
    mode: str
    condition: str
    score: Estimate
    final: Estimate  # IQM of the final score
    difference: Intervals | None  # from the control (None: the control itself)
    p: Estimate | None


@dataclass(frozen=True)
class Hypothesis:
    primary: Primary
    evidence: Evidence
    game: Game
    modes: tuple[str, ...]
    exchange_every: tuple[int, ...]  # episodes between two exchanges of `best`
    exchange_tau: tuple[float, ...]  # the soft copy's weight
    shared_learners: tuple[str, ...]  # the learners of the shared-network condition
    rows: list[ExchangeRow]
    p: Estimate | None  # the primary comparison's
    difference: Intervals | None
    panels: list[Panel]
    profiles: list[tuple[str, str, dict[str, np.ndarray]]]  # (learner, mode, {condition: final scores by map})


# ------------------------------------------------------------------------------------ claim 1


@dataclass(frozen=True)
class ModesRow:
    learner: str
    competitive: Estimate
    cooperative: Estimate
    difference: Intervals
    p: Estimate
    after_clear: tuple[float | None, float | None]  # competitive, cooperative; None: not recorded
    return_after_clear: tuple[float | None, float | None]


@dataclass(frozen=True)
class Claim1:
    primary: Primary
    evidence: Evidence
    game: Game
    margin: float
    final_tail: float
    rows: list[ModesRow]
    difference: Intervals | None  # the primary comparison's
    panels: list[Panel]


# ------------------------------------------------------------------------------------ claim 2


@dataclass(frozen=True)
class SizeRow:
    learner: str
    m: int
    levels: dict[str, Estimate]  # mode: score
    gaps: tuple[Intervals, Intervals]  # cooperative - competitive, deliberative - cooperative
    finals: dict[str, Estimate]  # mode: IQM of the final score


@dataclass(frozen=True)
class Trend:
    """A learner's gaps against team size: each gap's slope, the rule's verdict, P at the largest team."""

    learner: str
    slopes: dict[str, tuple[Estimate, Estimate]]  # gap: (bootstrap, t)
    verdict: str
    largest: int
    improvements: list[tuple[str, str, Estimate]]  # (a, b, P(a > b))
    levels: dict[str, dict[int, Estimate]]  # mode: {m: score}
    gaps: dict[str, dict[int, Estimate]]  # gap: {m: mean paired difference}


@dataclass(frozen=True)
class Claim2:
    primary: Primary
    evidence: Evidence
    sizes: list[int]
    map_sides: dict[int, tuple[int, ...]]  # m: its maps' sides
    as_many: bool  # as many chests and traps as agents, in every run
    final_tail: float
    rows: list[SizeRow]
    trends: list[Trend]
    slopes: dict[str, Estimate] | None  # the primary learner's bootstrap slopes


# ------------------------------------------------------------------------------------ claim 3: transfer


@dataclass(frozen=True)
class TransferRow:
    learner: str
    condition: str
    cost: int  # env steps spent on the source
    score: Estimate
    reached: int  # runs that reached the threshold
    runs: int
    jump: Estimate | None = None  # None: the baseline's own row
    difference: Intervals | None = None
    p: Estimate | None = None
    sooner: Estimate | None = None
    saved: float | None = None  # mean steps to the threshold saved against the baseline


@dataclass(frozen=True)
class Transfer:
    primary: Primary
    evidence: Evidence
    game: Game
    baseline: str
    matched_epsilon: tuple[float, ...]  # the baseline's exploration start
    scratch_epsilon: tuple[float, ...]
    threshold: float
    rows: list[TransferRow]
    p: Estimate | None
    difference: Intervals | None
    panels: list[Panel]
    total_panels: list[Panel]
    source_costs: list[int]


# ------------------------------------------------------------------------------------ curriculum


@dataclass(frozen=True)
class CurriculumRow:
    learner: str
    start: int  # total steps at the curriculum's first evaluation
    jump: Estimate
    difference: Intervals | None  # None: no shared steps
    finals: tuple[Estimate, Estimate]  # curriculum, scratch
    p: Estimate


@dataclass(frozen=True)
class Curriculum:
    primary: Primary
    evidence: Evidence
    game: Game
    room: Game
    room_offset: tuple[tuple[int, ...], ...]
    rows: list[CurriculumRow]
    panels: list[Panel]
    stage_ends: list[int]


Result = Hypothesis | Claim1 | Claim2 | Transfer | Curriculum
