"""Statistics over seeds: the percentile bootstrap, computed here and nowhere else.

Every interval of the package is a 95% percentile bootstrap of a mean over seeds: resample the
seeds with replacement, take the mean of each resample, and read the ``(1 - confidence)/2`` and
``(1 + confidence)/2`` quantiles of those means. Runs of different conditions that share a seed
share its map, initial weights and exploration noise, so differences between conditions are
paired by seed where they can be (:func:`difference`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dqn_transfer.analysis.transfer_metrics import Curve, common_steps

N_RESAMPLES = 10000
BAND_RESAMPLES = 2000  # a band is one interval per evaluation step: fewer resamples keep figures quick


def _resampled_means(values: np.ndarray, rng: np.random.Generator, n_resamples: int) -> np.ndarray:
    """Means of ``n_resamples`` resamples of ``values``' rows (axis 0), drawn with replacement."""
    indices = rng.integers(0, values.shape[0], size=(n_resamples, values.shape[0]))
    return values[indices].mean(axis=1)


def _percentiles(means: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    low, high = np.quantile(means, [(1.0 - confidence) / 2.0, (1.0 + confidence) / 2.0], axis=0)
    return low, high


def bootstrap_ci(values: Sequence[float] | np.ndarray, rng: np.random.Generator,
                 n_resamples: int = N_RESAMPLES, confidence: float = 0.95) -> tuple[float, float, float]:
    """``(mean, low, high)``: percentile-bootstrap interval of the mean over seeds.

    With a single value there is no spread to resample, so the interval is ``(nan, nan)`` rather
    than a falsely certain ``(v, v)``.
    """
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 1 or values.size == 0:
        raise ValueError("bootstrap_ci needs a non-empty 1-D sequence of values")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    mean = float(values.mean())
    if values.size == 1:
        return mean, math.nan, math.nan
    low, high = _percentiles(_resampled_means(values, rng, n_resamples), confidence)
    return mean, float(low), float(high)


@dataclass
class Estimate:
    """A mean over ``n`` seeds with its 95% bootstrap interval (``nan`` bounds: no interval)."""

    mean: float
    low: float
    high: float
    n: int

    @property
    def has_ci(self) -> bool:
        return math.isfinite(self.low) and math.isfinite(self.high)

    def excludes_zero_above(self) -> bool:
        return self.has_ci and self.low > 0

    def contains_zero(self) -> bool:
        return self.has_ci and self.low <= 0 <= self.high

    def __str__(self) -> str:
        if not math.isfinite(self.mean):
            return "n/a"
        ci = f"[{self.low:.4g}, {self.high:.4g}]" if self.has_ci else "[CI n/a]"
        return f"{self.mean:.4g} {ci}"


def estimate(values: Sequence[float], rng: np.random.Generator) -> Estimate:
    """:func:`bootstrap_ci` of the finite values (a run that never reached a threshold has none);
    ``n`` says how many values it rests on."""
    values = [v for v in values if math.isfinite(v)]
    if not values:
        return Estimate(math.nan, math.nan, math.nan, 0)
    return Estimate(*bootstrap_ci(values, rng), len(values))


def difference(a: dict[int, float], b: dict[int, float], rng: np.random.Generator,
               n_resamples: int = N_RESAMPLES, confidence: float = 0.95) -> Estimate:
    """Mean of ``a - b`` (each ``{seed: value}``) with a bootstrap CI: paired by seed when both have
    the same seeds (same map, same initial values and exploration noise cancel), else two
    independent samples, each resampled on its own."""
    if set(a) == set(b):
        return estimate([a[s] - b[s] for s in sorted(a)], rng)
    av, bv = np.array(list(a.values())), np.array(list(b.values()))
    mean = float(av.mean() - bv.mean())
    if av.size < 2 or bv.size < 2:
        return Estimate(mean, math.nan, math.nan, min(av.size, bv.size))
    diffs = _resampled_means(av, rng, n_resamples) - _resampled_means(bv, rng, n_resamples)
    low, high = _percentiles(diffs, confidence)
    return Estimate(mean, float(low), float(high), min(av.size, bv.size))


def curve_band(curves: Sequence[Curve], rng: np.random.Generator, confidence: float = 0.95,
               n_resamples: int = BAND_RESAMPLES) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(steps, mean, low, high)`` over runs at the steps they all share; percentile bootstrap per step.

    With a single run the band collapses to the curve itself (there is no spread to resample).
    """
    steps, values = common_steps(curves)  # [runs, steps]
    mean = values.mean(axis=0)
    if values.shape[0] == 1:
        return steps, mean, mean.copy(), mean.copy()
    low, high = _percentiles(_resampled_means(values, rng, n_resamples), confidence)
    return steps, mean, low, high
