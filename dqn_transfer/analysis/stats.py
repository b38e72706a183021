"""Statistics over runs, computed here and nowhere else.

- Means over seeds with a 95% percentile bootstrap: resample the seeds with replacement, take the
  mean of each resample, and read the ``(1 - confidence)/2`` and ``(1 + confidence)/2`` quantiles of
  those means. Runs of different conditions that share a seed share its map, initial weights and
  exploration noise, so differences between conditions are paired by seed where they can be. At
  small n a percentile interval is too narrow, so :func:`mean_intervals` gives the t and BCa intervals
  beside it.
- The field's robust aggregates, from ``rliable`` (Agarwal et al. 2021, "Deep RL at the edge of the
  statistical precipice"): the interquartile mean (:func:`iqm`) and the probability of improvement
  (:func:`improvement_probability`), each with rliable's stratified bootstrap (runs resampled within
  each task, i.e. map). Scores are ``[runs, tasks]``; a 1-D array is one task.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.stats
from rliable import library as rliable_library
from rliable import metrics as rliable_metrics

from dqn_transfer.analysis.transfer_metrics import Curve, common_steps

N_RESAMPLES = 10000
BAND_RESAMPLES = 2000  # a band is one interval per evaluation step: fewer resamples keep figures quick
RLIABLE_RESAMPLES = 2000  # stratified-bootstrap resamples of the IQM and the probability of improvement
Values = Sequence[float] | np.ndarray  # one value per run


def _resampled_means(values: np.ndarray, rng: np.random.Generator, n_resamples: int) -> np.ndarray:
    """Means of ``n_resamples`` resamples of ``values``' rows (axis 0), drawn with replacement."""
    indices = rng.integers(0, values.shape[0], size=(n_resamples, values.shape[0]))
    return values[indices].mean(axis=1)


def _percentiles(means: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    low, high = np.quantile(means, [(1.0 - confidence) / 2.0, (1.0 + confidence) / 2.0], axis=0)
    return low, high


def bootstrap_ci(
    values: Sequence[float] | np.ndarray,
    rng: np.random.Generator,
    n_resamples: int = N_RESAMPLES,
    confidence: float = 0.95,
) -> tuple[float, float, float]:
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

    def __str__(self) -> str:
        if not math.isfinite(self.mean):
            return "n/a"
        ci = f"[{self.low:.4g}, {self.high:.4g}]" if self.has_ci else "[CI n/a]"
        return f"{self.mean:.4g} {ci}"


def estimate(values: Values, rng: np.random.Generator) -> Estimate:
    """:func:`bootstrap_ci` of the finite values (a run that never reached a threshold has none);
    ``n`` says how many values it rests on."""
    values = [v for v in values if math.isfinite(v)]
    if not values:
        return Estimate(math.nan, math.nan, math.nan, 0)
    return Estimate(*bootstrap_ci(values, rng), len(values))


def curve_band(
    curves: Sequence[Curve], rng: np.random.Generator, confidence: float = 0.95, n_resamples: int = BAND_RESAMPLES
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(steps, mean, low, high)`` over runs at the steps they all share; percentile bootstrap per step.

    With a single run the band collapses to the curve itself (there is no spread to resample).
    """
    steps, values = common_steps(curves)  # [runs, steps]
    mean = values.mean(axis=0)
    if values.shape[0] == 1:
        return steps, mean, mean.copy(), mean.copy()
    low, high = _percentiles(_resampled_means(values, rng, n_resamples), confidence)
    return steps, mean, low, high


def mean_intervals(values: Values, rng: np.random.Generator, confidence: float = 0.95) -> dict[str, Estimate]:
    """The mean over runs with three 95% intervals: ``percentile`` (:func:`bootstrap_ci`), ``t`` (Student's
    t, which holds at small n for roughly normal values) and ``bca`` (bias-corrected and accelerated
    bootstrap, scipy's). Fewer than two values, or values all equal, give no interval (``nan``)."""
    finite = np.asarray([v for v in values if math.isfinite(v)], dtype=np.float64)
    n = finite.size
    if n < 2 or np.all(finite == finite[0]):
        mean = float(finite.mean()) if n else math.nan
        return {method: Estimate(mean, math.nan, math.nan, n) for method in ("percentile", "t", "bca")}
    mean = float(finite.mean())
    t_low, t_high = scipy.stats.t.interval(confidence, n - 1, loc=mean, scale=scipy.stats.sem(finite))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # near-degenerate samples: scipy warns and returns nan, shown as "n/a"
        bca = scipy.stats.bootstrap(
            (finite,), np.mean, confidence_level=confidence, method="BCa", n_resamples=N_RESAMPLES, random_state=rng
        ).confidence_interval
    return {
        "percentile": Estimate(*bootstrap_ci(finite, rng, confidence=confidence), n),
        "t": Estimate(mean, float(t_low), float(t_high), n),
        "bca": Estimate(mean, float(bca.low), float(bca.high), n),
    }


def _as_runs_by_tasks(scores: Sequence[float] | np.ndarray) -> np.ndarray:
    scores = np.asarray(scores, dtype=np.float64)
    scores = scores[:, None] if scores.ndim == 1 else scores
    if scores.ndim != 2 or scores.shape[0] == 0:
        raise ValueError(f"scores are [runs, tasks] (or [runs]) with at least one run, got shape {list(scores.shape)}")
    return scores


def _stratified_resample(scores: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``[resamples, runs, tasks]``: the runs of each task resampled with replacement, independently per
    task (rliable's ``StratifiedBootstrap``)."""
    runs, tasks = scores.shape
    indices = rng.integers(0, runs, size=(RLIABLE_RESAMPLES, runs, tasks))
    return np.take_along_axis(np.broadcast_to(scores, (RLIABLE_RESAMPLES, runs, tasks)), indices, axis=1)


def percentile_estimate(point: float, resampled: np.ndarray, confidence: float, n: int) -> Estimate:
    """``point`` with the percentile interval of its bootstrap ``resampled`` values.

    :param point: the statistic of the data.
    :param resampled: its value on each resample ``[resamples]``.
    :param confidence: the interval's coverage, in (0, 1).
    :param n: how many units the estimate rests on.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    low, high = _percentiles(resampled, confidence)
    return Estimate(point, float(low), float(high), n)


def no_interval(point: float, n: int) -> Estimate:
    """An estimate without an interval: one unit has no spread to resample (not a falsely certain one)."""
    return Estimate(point, math.nan, math.nan, n)


def iqm(scores: Sequence[float] | np.ndarray, rng: np.random.Generator, confidence: float = 0.95) -> Estimate:
    """The interquartile mean (the mean of the middle 50% of all runs' scores, pooled over tasks; robust to
    a few outlying runs, less noisy than the median; rliable's ``aggregate_iqm``) with a stratified-bootstrap
    percentile interval. The :class:`Estimate`'s ``mean`` holds the IQM; ``n`` counts the runs."""
    scores = _as_runs_by_tasks(scores)
    point = float(rliable_metrics.aggregate_iqm(scores))
    if scores.shape[0] < 2:
        return no_interval(point, scores.shape[0])
    resampled = _stratified_resample(scores, rng).reshape(RLIABLE_RESAMPLES, -1)
    return percentile_estimate(point, scipy.stats.trim_mean(resampled, 0.25, axis=1), confidence, scores.shape[0])


def improvement_by_task(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``[..., tasks]``: P(X > Y) within each task from runs ``x [..., tasks, n_x]`` and ``y [..., tasks, n_y]``
    (``nan``: no run), a tie counting one half: the Mann-Whitney U statistic over the pairs present."""
    xs, ys = x[..., :, None], y[..., None, :]
    present = ~np.isnan(xs) & ~np.isnan(ys)
    wins = np.where(present, (xs > ys) + 0.5 * (xs == ys), 0.0)
    return wins.sum(axis=(-2, -1)) / present.sum(axis=(-2, -1))


def improvement_probability(
    x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, rng: np.random.Generator, confidence: float = 0.95
) -> Estimate:
    """P(X > Y): the probability that a run of condition ``x`` scores higher than a run of ``y`` on the
    same task (a tie counts one half; the Mann-Whitney U statistic over n_x * n_y), averaged over
    tasks (rliable's ``probability_of_improvement``), with a stratified-bootstrap percentile interval.
    0.5 is no difference; an interval above 0.5 says x is better. Ranks only: an ``inf`` score (a run
    that never reached a threshold, counted as slower than every run that did) is fine. ``n`` counts
    the smaller condition's runs.

    The point is rliable's own function. The interval resamples as rliable's ``get_interval_estimates``
    does (each condition's runs within each task, independently), vectorised in numpy: rliable's
    bootstrap (through ``arch``) takes about 4.5 s per comparison over 5 maps, this about 10 ms, and a
    report makes dozens (``tests/test_stats.py`` checks the two intervals agree)."""
    x, y = _as_runs_by_tasks(x), _as_runs_by_tasks(y)
    if x.shape[1] != y.shape[1]:
        raise ValueError(f"x and y must have the same tasks: {x.shape[1]} and {y.shape[1]}")
    n = min(x.shape[0], y.shape[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # inf - inf inside scipy's ranks: the ties are right
        point = float(rliable_metrics.probability_of_improvement(x, y))
    if n < 2:
        return no_interval(point, n)
    x_drawn, y_drawn = (np.swapaxes(_stratified_resample(runs, rng), -1, -2) for runs in (x, y))
    resampled = improvement_by_task(x_drawn, y_drawn).mean(axis=-1)
    return percentile_estimate(point, resampled, confidence, n)


def performance_profile(
    scores: Sequence[float] | np.ndarray, taus: np.ndarray, rng: np.random.Generator, confidence: float = 0.95
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(profile, low, high)``: the fraction of runs (over every task) scoring above each ``tau``
    (rliable's ``score_distributions``), with a stratified-bootstrap percentile band, resampled as
    :func:`iqm` does (rliable's own bootstrap seeds itself and differs in the last bits from call to call,
    so a regenerated figure would not be identical)."""
    scores = _as_runs_by_tasks(scores)
    profile = np.asarray(rliable_library.score_distributions(scores, taus), dtype=np.float64)
    resampled = _stratified_resample(scores, rng).reshape(RLIABLE_RESAMPLES, -1)
    fractions = (resampled[:, :, None] > taus[None, None, :]).mean(axis=1)  # [resamples, taus]
    low, high = _percentiles(fractions, confidence)
    return profile, low, high
