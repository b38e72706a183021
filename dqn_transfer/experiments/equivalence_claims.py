"""The third edition's analysis (``results/VERDICT_RULES.md``): runs to normalised scores over a fixed
horizon, and a cell's comparisons to outcomes against the smallest effect of interest and to verdicts.

A run's **normalised score** puts the random team of its map at 0 and the oracle at 1
(:func:`~dqn_transfer.analysis.equivalence.normalised`); its **normalised AUC** (the primary outcome) is
the mean of that score over the run's evaluations after step 0 up to the horizon, its **final score**
the mean over the horizon's last 20%. The random team's return on a map (:func:`random_team_return`) is
played again from the run's recorded config, seeded, so every number here comes from the committed data.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np

from dqn_transfer.analysis.equivalence import Contrast, Outcome, contrast, normalised, outcomes
from dqn_transfer.analysis.hierarchical import holm
from dqn_transfer.envs import Game, PettingZooGame, make_game
from dqn_transfer.envs.settings import ENV_KEYS
from dqn_transfer.evaluation import bounds
from dqn_transfer.experiments.hierarchical_claims import values_by_map
from dqn_transfer.experiments.power import differences_by_map
from dqn_transfer.experiments.raw_data import RunData

HORIZON = 16_000  # every run's env steps
FINAL_SHARE = 0.2  # the final score: the evaluations of a run's last 20% (13,000 .. 16,000 at the horizon)
SESOI = 0.03  # the smallest effect of interest, in normalised AUC (and final score)
RANDOM_EPISODES = 100  # the random team's episodes on a map (seed 0): a normalised score's zero
CONTROLS = {"sham": Outcome.equivalent, "warm": Outcome.better}  # each control's required outcome against none


class Verdict(Enum):
    """The main hypothesis in one cell, from its primary methods' outcomes."""

    supported = "SUPPORTED"  # at least one method better
    contradicted = "CONTRADICTED"  # none better, at least one worse
    no_useful_effect = "NO USEFUL EFFECT"  # every method equivalent
    inconclusive = "INCONCLUSIVE"


def random_team_return(run: RunData) -> float:
    """The random team's mean team return on the run's map (the treasure hunt) or instance (another game,
    ``env.fixed_start``): :data:`RANDOM_EPISODES` episodes of seed 0, the same for every run of the map."""
    return _random_team_return(json.dumps(run.config["env"], sort_keys=True))


@functools.cache
def _random_team_return(env_json: str) -> float:
    env: dict[str, Any] = json.loads(env_json)
    if env.get("factory") is not None:
        instance = env["map_seed"] if env.get("fixed_start") else None
        game: Game = PettingZooGame(env["factory"], env.get("kwargs") or {}, instance)
    else:
        game = make_game(**{key: env[key] for key in ENV_KEYS if env.get(key) is not None})
    return bounds.random_team_return(game, RANDOM_EPISODES, seed=0)


def oracle_return(run: RunData) -> float:
    """A normalised score's one: the map's optimal team return; another game's, LBF's, is 1; on a map with
    more agents than chests, which has no clean optimum (the paper's Figure 1), every chest's reward."""
    if run.optimal_return is not None:
        return run.optimal_return
    env = run.config["env"]
    if env.get("factory") is not None:
        return 1.0
    return float(env.get("treasure_reward", 100.0)) * int(env["num_treasures"])


def normalised_curve(run: RunData, random_return: float) -> tuple[np.ndarray, np.ndarray]:
    """The run's evaluations after step 0 up to the horizon, as normalised scores (:func:`oracle_return`)."""
    steps, returns = run.curve()
    kept = (steps > 0) & (steps <= HORIZON)
    return steps[kept], np.asarray(normalised(returns[kept], random_return, oracle_return(run)))


def normalised_auc(run: RunData, random_return: float) -> float:
    """The primary outcome: the mean normalised score over the run's evaluations."""
    return float(normalised_curve(run, random_return)[1].mean())


def final_score(run: RunData, random_return: float) -> float:
    """The secondary outcome: the mean normalised score of the last 20% of the run's steps."""
    steps, scores = normalised_curve(run, random_return)
    return float(scores[steps >= final_from(run)].mean())


def final_from(run: RunData) -> float:
    """The first step of a run's final score: its last 20% of steps (13,000 at the horizon)."""
    return (1.0 - FINAL_SHARE) * min(int(run.config["total_steps"]), HORIZON)


def auc_value(run: RunData) -> float:
    """A run's normalised AUC against its map's random team."""
    return normalised_auc(run, random_team_return(run))


def final_value(run: RunData) -> float:
    """A run's final score against its map's random team."""
    return final_score(run, random_team_return(run))


@dataclass(frozen=True)
class Comparison:
    """One condition against ``none`` in a cell: the contrast and its outcome within its family."""

    name: str
    contrast: Contrast
    outcome: Outcome
    p_difference: float  # Holm-adjusted within the family
    p_equivalence: float


def family(
    runs: Mapping[str, Sequence[RunData]],
    names: Sequence[str],
    value: Callable[[RunData], float],
    against: str = "none",
) -> list[Comparison]:
    """Each of ``names`` against ``against``, paired by (map, seed), its outcome Holm-adjusted within them."""
    contrasts = [contrast(differences_by_map(runs[name], runs[against], value), SESOI) for name in names]
    adjusted = zip(holm([c.p_difference for c in contrasts]), holm([c.p_equivalence for c in contrasts]))
    return [
        Comparison(name, c, o, float(pd), float(pe))
        for name, c, o, (pd, pe) in zip(names, contrasts, outcomes(contrasts), adjusted)
    ]


def verdict(primary: Sequence[Comparison]) -> Verdict:
    """The main hypothesis in a cell, from its primary family's outcomes."""
    found = {comparison.outcome for comparison in primary}
    if Outcome.better in found:
        return Verdict.supported
    if Outcome.worse in found:
        return Verdict.contradicted
    if found == {Outcome.equivalent}:
        return Verdict.no_useful_effect
    return Verdict.inconclusive


def failed_controls(controls: Sequence[Comparison]) -> list[str]:
    """The controls whose outcome is not the one they must have (an empty list: the cell is validated)."""
    return [c.name for c in controls if c.outcome is not CONTROLS[c.name]]


def room(none: Sequence[RunData], value: Callable[[RunData], float]) -> Contrast:
    """Oracle − ``none`` in a cell: 1 minus its runs' value, over the maps (the most any method could add)."""
    return contrast(values_by_map(none, lambda run: 1.0 - value(run)), SESOI)
