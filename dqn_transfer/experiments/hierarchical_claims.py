"""The registered questions (the second edition's), answered from the raw data by its rules
(``results/v2/VERDICT_RULES.md``).

Every interval is the hierarchical bootstrap's (:mod:`dqn_transfer.analysis.hierarchical`); every p-value its
two-sided bootstrap p, adjusted by Holm over a registered family. Pure functions of the data and one random
stream: the same data and seed give the same digits.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from dqn_transfer.analysis.hierarchical import (
    MeanDifference,
    fraction_below,
    hierarchical_bootstrap,
    holm,
    independent_mean_difference,
    iqm_of_runs,
    mean_of_runs,
    paired_mean_difference,
    paired_slope,
    power,
    probability_of_improvement,
    variance_components,
)
from dqn_transfer.analysis.stats import Estimate
from dqn_transfer.analysis.transfer_metrics import asymptotic_performance
from dqn_transfer.enums import Bound
from dqn_transfer.envs.game import make_game
from dqn_transfer.envs.settings import ENV_KEYS
from dqn_transfer.evaluation.bounds import evaluate_bound
from dqn_transfer.experiments.claims import margin_verdict, trend_verdict
from dqn_transfer.experiments.raw_data import RunData
from dqn_transfer.experiments.results import INCONCLUSIVE
from dqn_transfer.experiments.scoring import FINAL_TAIL, final_score, group, learner, learners, mode, team_size
from dqn_transfer.experiments.scoring import score as auc_score  # the mean score over training

FAILURE_BELOW = 0.5  # a run fails when its final score is under half the optimal return
SMALLEST_EFFECT = 0.10  # in final score: the registered smallest effect of interest
ALPHA = 0.05  # family-wise, Holm
CLAIM1_MARGIN = 5.0  # return units
PRIMARY_METHODS = ("shared_replay", "confidence", "advice")  # SARSA's primary family, each against none
SECONDARY_METHODS = ("shared_replay", "experience", "shared_id")  # Double DQN's
CLAIM3_METHODS = ("same_map_own", "same_map_own_aware")  # against scratch_matched
BOUND_EPISODES = 5  # the greedy floor's evaluation, as a learner's (eval_episodes)

RunValue = Callable[[RunData], float]


# ------------------------------------------------------------------------------------------- conditions


def method(run: RunData) -> str:
    """The run's knowledge-exchange method, as ``conf/method/`` names it (after the learner)."""
    agent = run.config["agent"]
    if agent.get("mixer", "none") == "vdn":
        return "vdn"
    if agent.get("share_parameters") and agent.get("agent_id_input"):
        return "shared_id"
    return str(run.config["transfer"]["exchange"])


def transfer_condition(run: RunData) -> str:
    """Claim 3's condition (``conf/condition/``) of a run."""
    transfer = run.config["transfer"]
    if not transfer["enabled"]:
        return "scratch" if float(run.config["agent"]["eps_start"]) == 1.0 else "scratch_matched"
    if transfer.get("source_task") == "per_agent":
        return "same_map_own_aware" if transfer.get("chest_aware") else "same_map_own"
    return "same_map"


def select(runs: Sequence[RunData], **conditions: Callable[[RunData], object] | object) -> list[RunData]:
    """The runs whose named properties (``learner=``, ``mode=``, ``method=``, ...) have the given values."""
    properties = {"learner": learner, "mode": mode, "method": method, "condition": transfer_condition}
    return [r for r in runs if all(properties[k](r) == v for k, v in conditions.items())]


# ------------------------------------------------------------------------------------------- run values


def final_return(run: RunData) -> float:
    """The final team return in return units (claim 1: its maps have no optimum)."""
    return asymptotic_performance(run.curve(), FINAL_TAIL)


def values_by_map(runs: Sequence[RunData], value: RunValue) -> list[np.ndarray]:
    """The runs' values, one array per map (maps in seed order, runs in seed order)."""
    maps = group(runs, lambda r: r.map_seed)
    return [np.array([value(r) for r in maps[m]]) for m in sorted(maps)]


def paired_by_map(x: Sequence[RunData], y: Sequence[RunData], value: RunValue) -> tuple[list[np.ndarray], ...]:
    """``(x values, y values)`` by map over the (map, seed) units both conditions ran, aligned."""
    shared = {r.unit for r in x} & {r.unit for r in y}
    return tuple(values_by_map([r for r in runs if r.unit in shared], value) for runs in (x, y))


# ------------------------------------------------------------------------------------------- summaries


@dataclass(frozen=True)
class Summary:
    """One condition's runs: the mean, IQM and failure rate of a value, each with its hierarchical interval."""

    mean: Estimate
    iqm: Estimate
    failure: Estimate | None  # None where the value is not a score (claim 1's return)
    runs: int


def summarize(runs: Sequence[RunData], value: RunValue, rng: np.random.Generator, score: bool = True) -> Summary:
    by_map = values_by_map(runs, value)
    failure = partial(fraction_below, threshold=FAILURE_BELOW)
    return Summary(
        hierarchical_bootstrap(by_map, mean_of_runs, rng),
        hierarchical_bootstrap(by_map, iqm_of_runs, rng),
        hierarchical_bootstrap(by_map, failure, rng) if score else None,
        len(runs),
    )


@dataclass(frozen=True)
class Difference:
    """X − Y paired by (map, seed): the mean difference, P(X > Y) within maps, and the power the design had
    for the smallest effect of interest at the variance components of these differences."""

    label: str
    difference: MeanDifference
    improvement: Estimate
    power: float
    holm_p: float | None = None  # set for a registered family's members

    @property
    def significant(self) -> bool:
        p = self.difference.p_value if self.holm_p is None else self.holm_p
        return math.isfinite(p) and p < ALPHA

    @property
    def sign(self) -> int:
        """+1 / -1 when significant in that direction, 0 when not."""
        return int(np.sign(self.difference.estimate.mean)) if self.significant else 0


def difference(
    label: str, x: Sequence[RunData], y: Sequence[RunData], value: RunValue, rng: np.random.Generator, alpha: float
) -> Difference:
    """X − Y by the registered analysis; the power is at ``alpha`` (the strictest Holm step of its family)."""
    xs, ys = paired_by_map(x, y, value)
    diffs = [a - b for a, b in zip(xs, ys)]
    return Difference(
        label,
        paired_mean_difference(diffs, rng),
        probability_of_improvement(xs, ys, rng, paired_seeds=True),
        achieved_power(diffs, rng, alpha),
    )


def achieved_power(diffs: Sequence[np.ndarray], rng: np.random.Generator, alpha: float) -> float:
    """The power the design had for the smallest effect of interest, at the variance components of its own
    paired differences (one run a map, as Double DQN's: map and run variance cannot be told apart, and all
    of it counts as the maps'); nan with fewer than two maps."""
    if len(diffs) < 2:
        return math.nan
    if all(d.size == 1 for d in diffs):
        sigma_map, sigma_run, seeds = float(np.std([d[0] for d in diffs], ddof=1)), 0.0, 1
    else:
        components = variance_components(diffs)
        sigma_map, sigma_run = components.sigma_map, components.sigma_run
        seeds = max(1, round(components.n_runs / components.n_maps))
    return power(SMALLEST_EFFECT, sigma_map, sigma_run, len(diffs), seeds, rng, alpha)


def family(differences: Sequence[Difference]) -> list[Difference]:
    """The family with its Holm-adjusted p-values."""
    adjusted = holm([d.difference.p_value for d in differences])
    return [Difference(d.label, d.difference, d.improvement, d.power, float(p)) for d, p in zip(differences, adjusted)]


def family_verdict(members: Sequence[Difference]) -> str:
    """SUPPORTED if a member is significantly positive, CONTRADICTED if none is and one is significantly
    negative, NOT SUPPORTED otherwise (INCONCLUSIVE with no member)."""
    if not members:
        return "INCONCLUSIVE"
    signs = {d.sign for d in members}
    if 1 in signs:
        return "SUPPORTED"
    return "CONTRADICTED" if -1 in signs else "NOT SUPPORTED"


# ------------------------------------------------------------------------------------------- the hypothesis


@dataclass(frozen=True)
class MethodRow:
    learner: str
    mode: str
    method: str
    final: Summary  # at the budget B
    half: Summary  # at B/2
    auc: Summary
    against_none: Difference | None  # final score at B; None for none itself
    against_none_half: Difference | None


@dataclass(frozen=True)
class HypothesisResult:
    rows: list[MethodRow]
    primary: list[Difference]  # SARSA, cooperative, Holm over PRIMARY_METHODS
    secondary: list[Difference]  # Double DQN, cooperative, Holm over SECONDARY_METHODS
    verdict: str
    secondary_verdict: str
    primary_mode: str  # the families' mode (cooperative; another game's runs carry their own)
    budgets: dict[tuple[str, str], int] = field(default_factory=dict)


def _budget(runs: Sequence[RunData]) -> int:
    return max(int(r.config["total_steps"]) for r in runs)


def hypothesis(
    runs: Sequence[RunData], rng: np.random.Generator, primary_mode: str = "cooperative"
) -> HypothesisResult:
    """The main hypothesis (or its replication: ``primary_mode`` is the mode LBF's runs carry)."""
    rows: list[MethodRow] = []
    primary: list[Difference] = []
    secondary: list[Difference] = []
    budgets: dict[tuple[str, str], int] = {}
    for algorithm in learners(runs):
        for run_mode in sorted({mode(r) for r in select(runs, learner=algorithm)}):
            cell = select(runs, learner=algorithm, mode=run_mode)
            budget = _budget(cell)
            budgets[(algorithm, run_mode)] = budget
            control = select(cell, method="none")
            methods = sorted({method(r) for r in cell}, key=lambda m: (m != "none", m))
            family_methods = PRIMARY_METHODS if algorithm == "sarsa" else SECONDARY_METHODS
            alpha = ALPHA / len(family_methods)
            at_half = partial(final_score, budget=budget // 2)
            members = []
            for name in methods:
                mine = select(cell, method=name)
                final, half, auc = [summarize(mine, value, rng) for value in (final_score, at_half, auc_score)]
                vs, vs_half = [
                    None if name == "none" else difference(name, mine, control, value, rng, alpha)
                    for value in (final_score, at_half)
                ]
                rows.append(MethodRow(algorithm, run_mode, name, final, half, auc, vs, vs_half))
                if name in family_methods and vs is not None:
                    members.append(vs)
            if run_mode == primary_mode:
                (primary if algorithm == "sarsa" else secondary).extend(family(members))
    return HypothesisResult(
        rows, primary, secondary, family_verdict(primary), family_verdict(secondary), primary_mode, budgets
    )


def replicated(treasure: HypothesisResult, other: HypothesisResult) -> str:
    """REPLICATED if the other game's primary verdict and significantly positive methods equal the treasure
    hunt's, NOT REPLICATED otherwise."""

    def positive(result: HypothesisResult) -> set[str]:
        return {d.label for d in result.primary if d.sign > 0}

    same = treasure.verdict == other.verdict and positive(treasure) == positive(other)
    return "REPLICATED" if same else "NOT REPLICATED"


# ------------------------------------------------------------------------------------------- claim 1


@dataclass(frozen=True)
class Claim1Result:
    competitive: Summary
    cooperative: Summary
    difference: Difference  # cooperative - competitive, final team return
    verdict: str


def claim1(runs: Sequence[RunData], rng: np.random.Generator) -> Claim1Result:
    comp, coop = select(runs, mode="competitive"), select(runs, mode="cooperative")
    diff = difference("cooperative - competitive", coop, comp, final_return, rng, ALPHA)
    return Claim1Result(
        summarize(comp, final_return, rng, score=False),
        summarize(coop, final_return, rng, score=False),
        diff,
        margin_verdict(diff.difference.estimate, CLAIM1_MARGIN),
    )


# ------------------------------------------------------------------------------------------- claim 2

MODES = ("competitive", "cooperative", "deliberative")
MODE_PAIRS = (("deliberative", "cooperative"), ("cooperative", "competitive"))


def contention(run: RunData) -> str:
    return str(run.config["env"].get("contention", "any"))


@dataclass(frozen=True)
class Claim2Cell:
    contention: str
    m: int
    modes: dict[str, Summary]
    differences: dict[tuple[str, str], MeanDifference]  # paired, final score at B


@dataclass(frozen=True)
class Claim2Result:
    cells: list[Claim2Cell]
    floors: dict[tuple[str, int, str], Estimate]  # (contention, m, mode) -> the greedy team's score over maps
    slopes: dict[tuple[str, tuple[str, str]], MeanDifference]  # (contention, pair) -> slope over m
    contention_effects: dict[tuple[int, tuple[str, str]], MeanDifference]  # (m, pair) -> high - low
    verdict: str


def _pair_differences(runs: Sequence[RunData], pair: tuple[str, str]) -> list[np.ndarray]:
    xs, ys = paired_by_map(select(runs, mode=pair[0]), select(runs, mode=pair[1]), final_score)
    return [a - b for a, b in zip(xs, ys)]


def greedy_floor(run: RunData) -> float:
    """The score of the greedy nearest-chest team (``docs/bounds.md``) on a run's map and mode: one map's
    floor, the same for every seed."""
    env = run.config["env"]
    game = make_game(**{key: env[key] for key in ENV_KEYS if env.get(key) is not None})
    record = evaluate_bound(game, Bound.greedy, BOUND_EPISODES, seed=0)
    return float(record["team_return"]) / float(run.optimal_return or 1.0)


def _floor(runs: Sequence[RunData], rng: np.random.Generator) -> Estimate:
    one_per_map = {run.map_seed: run for run in runs}
    return hierarchical_bootstrap([np.array([greedy_floor(r)]) for r in one_per_map.values()], mean_of_runs, rng)


def claim2(runs: Sequence[RunData], rng: np.random.Generator) -> Claim2Result:
    cells, slopes, effects, floors = [], {}, {}, {}
    levels = sorted({contention(r) for r in runs})
    sizes = sorted({team_size(r) for r in runs})
    by_cell = {(c, m): [r for r in runs if contention(r) == c and team_size(r) == m] for c in levels for m in sizes}
    for c in levels:
        for m in sizes:
            cell = by_cell[(c, m)]
            cells.append(
                Claim2Cell(
                    c,
                    m,
                    {name: summarize(select(cell, mode=name), final_score, rng) for name in MODES},
                    {pair: paired_mean_difference(_pair_differences(cell, pair), rng) for pair in MODE_PAIRS},
                )
            )
            for name in MODES:
                floors[(c, m, name)] = _floor(select(cell, mode=name), rng)
        for pair in MODE_PAIRS:
            slopes[(c, pair)] = paired_slope({m: _pair_differences(by_cell[(c, m)], pair) for m in sizes}, rng)
    if {"high", "low"} <= set(levels):
        for m in sizes:
            for pair in MODE_PAIRS:
                effects[(m, pair)] = independent_mean_difference(
                    _pair_differences(by_cell[("high", m)], pair), _pair_differences(by_cell[("low", m)], pair), rng
                )
    primary = [slopes[("high", pair)].estimate for pair in MODE_PAIRS] if "high" in levels else []
    verdict = trend_verdict(primary) if primary else INCONCLUSIVE
    return Claim2Result(cells, floors, slopes, effects, verdict)


# ------------------------------------------------------------------------------------------- claim 3


@dataclass(frozen=True)
class TransferRow:
    learner: str
    condition: str
    auc: Summary
    final: Summary
    against_control: Difference | None  # AUC score over the target's own steps
    at_total_steps: Difference | None  # final score at equal total steps (the sources' steps counted)


@dataclass(frozen=True)
class Claim3Result:
    rows: list[TransferRow]
    primary: list[Difference]
    verdict: str


def final_at_total_steps(run: RunData, total: int) -> float:
    """The final score at ``total`` env steps in all: a warm-started run's own curve cut where its steps and
    its sources' pretraining steps reach ``total``."""
    return final_score(run, total - run.steps_before)


def claim3(runs: Sequence[RunData], rng: np.random.Generator) -> Claim3Result:
    rows, primary = [], []
    for algorithm in learners(runs):
        cell = select(runs, learner=algorithm)
        control = select(cell, condition="scratch_matched")
        budget = _budget(cell)
        at_total = partial(final_at_total_steps, total=budget)
        conditions = sorted({transfer_condition(r) for r in cell}, key=lambda c: (c != "scratch_matched", c))
        alpha = ALPHA / len(CLAIM3_METHODS)
        members = []
        for name in conditions:
            mine = select(cell, condition=name)
            auc, final = [summarize(mine, value, rng) for value in (auc_score, final_score)]
            vs, at_equal_total = [
                None if name == "scratch_matched" else difference(name, mine, control, value, rng, alpha)
                for value in (auc_score, at_total)
            ]
            rows.append(TransferRow(algorithm, name, auc, final, vs, at_equal_total))
            if name in CLAIM3_METHODS and vs is not None:
                members.append(vs)
        if algorithm == "sarsa":
            primary = family(members)
    return Claim3Result(rows, primary, family_verdict(primary))
