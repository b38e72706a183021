"""A difference judged against a smallest effect of interest: better, equivalent, worse or inconclusive.

The study's third edition compares two conditions X and Y on paired runs (same map, same seed) and asks
not only *whether* X differs from Y but whether the difference matters: a registered smallest effect of
interest (SESOI, ``delta``) separates a useful effect from a negligible one (Lakens 2017, "Equivalence
tests", Social Psychological and Personality Science 8(4)).

The unit of inference is the map. Each map contributes the mean of its paired differences (its seeds
averaged), and the maps are a random sample of the population their generator defines, so a Student t
interval over the map means speaks of that population. Averaging a map's seeds first counts their noise
once: the spread of the map means already holds it (resampling the seeds again, as the second edition's
two-stage bootstrap did, counts it twice). Two tests are made of each difference:

- **difference**: the two-sided t-test of "no difference" (``p_difference``);
- **equivalence**: two one-sided t-tests (TOST) of "at most ``-delta``" and "at least ``+delta``";
  ``p_equivalence`` is the larger of their p-values, and it is below ``alpha`` exactly when the
  ``1 - 2 alpha`` interval lies inside ``(-delta, +delta)``.

Within a family of comparisons each kind of p-value is adjusted by Holm's method, and the
:class:`Outcome` is read from the adjusted pair: **equivalent** if the equivalence test rejects (a
difference that is there but smaller than ``delta`` is equivalent too: negligible), else **better** or
**worse** if the difference test rejects, by the sign of the mean, else **inconclusive**.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np
import scipy.stats

from dqn_transfer.analysis.hierarchical import holm

ALPHA = 0.05  # family-wise, for each of the two tests
POWER_TARGET = 0.8


class Outcome(Enum):
    """What a difference X - Y is, against the smallest effect of interest."""

    better = "better"  # X above Y, by an amount not shown to be below delta
    equivalent = "equivalent"  # |X - Y| shown below delta
    worse = "worse"  # X below Y, by an amount not shown to be below delta
    inconclusive = "inconclusive"  # neither shown


@dataclass(frozen=True)
class Contrast:
    """The mean paired difference X - Y over maps, its intervals and its two tests' p-values (unadjusted)."""

    mean: float
    low: float  # the 1 - alpha interval
    high: float
    low_tost: float  # the 1 - 2 alpha interval, the one the equivalence test reads
    high_tost: float
    n_maps: int
    p_difference: float
    p_equivalence: float


def contrast(
    differences_by_map: Sequence[Sequence[float] | np.ndarray], delta: float, alpha: float = ALPHA
) -> Contrast:
    """The contrast of paired differences, one array (its seeds) per map, against the SESOI ``delta``."""
    means = np.array([np.mean(np.asarray(d, dtype=np.float64)) for d in differences_by_map])
    n = means.size
    if n < 2:
        raise ValueError(f"a contrast needs two maps or more, got {n}")
    mean, se = float(means.mean()), float(means.std(ddof=1) / math.sqrt(n))
    t = scipy.stats.t(df=n - 1)
    if se == 0.0:  # every map the same difference: it is known exactly
        differs, within = mean != 0.0, abs(mean) < delta
        return Contrast(mean, mean, mean, mean, mean, n, 0.0 if differs else 1.0, 0.0 if within else 1.0)
    p_difference = float(2.0 * t.sf(abs(mean) / se))
    p_above_minus = float(t.sf((mean + delta) / se))  # H0: mean <= -delta
    p_below_plus = float(t.cdf((mean - delta) / se))  # H0: mean >= +delta
    wide, narrow = t.ppf(1.0 - alpha / 2.0) * se, t.ppf(1.0 - alpha) * se
    return Contrast(
        mean, mean - wide, mean + wide, mean - narrow, mean + narrow, n, p_difference, max(p_above_minus, p_below_plus)
    )


def outcomes(family: Sequence[Contrast], alpha: float = ALPHA) -> list[Outcome]:
    """Each contrast's outcome, both tests Holm-adjusted within ``family`` (the registered comparisons)."""
    if not family:
        return []
    differs = holm([c.p_difference for c in family]) < alpha
    within = holm([c.p_equivalence for c in family]) < alpha
    return [
        Outcome.equivalent
        if eq
        else (Outcome.better if c.mean > 0 else Outcome.worse)
        if diff
        else Outcome.inconclusive
        for c, diff, eq in zip(family, differs, within)
    ]


def power(delta: float, sigma_map: float, sigma_run: float, n_maps: int, n_seeds: int, alpha: float = ALPHA) -> float:
    """The probability that the two-sided t-test of ``n_maps`` map means (``n_seeds`` seeds each) detects a
    true difference of ``delta`` at level ``alpha``, when map effects vary by ``sigma_map`` and runs on a
    map by ``sigma_run`` (normal random effects; the noncentral t distribution)."""
    if n_maps < 2:
        raise ValueError(f"power needs two maps or more, got {n_maps}")
    se = math.sqrt((sigma_map**2 + sigma_run**2 / n_seeds) / n_maps)
    if se == 0.0:  # no spread at all: any difference is seen
        return 1.0
    df, critical = n_maps - 1, scipy.stats.t.ppf(1.0 - alpha / 2.0, n_maps - 1)
    shift = delta / se
    # The lower tail P(T < -c; shift) as P(T > c; -shift): scipy's nct.cdf gives nan where it underflows.
    return float(scipy.stats.nct.sf(critical, df, shift) + scipy.stats.nct.sf(critical, df, -shift))


def maps_for_power(
    delta: float, sigma_map: float, sigma_run: float, n_seeds: int, alpha: float = ALPHA, target: float = POWER_TARGET
) -> int:
    """The fewest maps whose :func:`power` at ``delta`` reaches ``target`` (power grows with the maps)."""
    n = 2
    while power(delta, sigma_map, sigma_run, n, n_seeds, alpha) < target:
        n += 1
    return n


def normalised(value: float | np.ndarray, floor: float, ceiling: float) -> float | np.ndarray:
    """``value`` on the scale where ``floor`` (a uniformly random team) is 0 and ``ceiling`` (the oracle) 1."""
    return (value - floor) / (ceiling - floor)
