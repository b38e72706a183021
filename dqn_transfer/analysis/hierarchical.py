"""The hierarchical (two-stage) bootstrap: the population of maps is the unit of inference.

:mod:`~dqn_transfer.analysis.stats` resamples runs (seeds) within the study's maps, so its intervals speak of
*those* maps; two seeds on one map count as two independent units although they share the map's layout.
Here every interval speaks of the population the maps were generated from: each resample draws the maps
with replacement, then, within each drawn map, its runs with replacement (Efron & Tibshirani 1993; Davison &
Hinkley 1997, section 3.8). A map drawn twice has its runs redrawn independently each time.

Data are a sequence of per-map arrays of run values (one value per run; maps may hold unequal numbers of
runs). A statistic sees the pooled runs of a resample, as a ``[..., runs]`` array padded with ``nan`` where
a resample holds fewer runs than the widest (so statistics here ignore ``nan``, and run values must be
finite).

The two-stage bootstrap errs two ways. It counts run noise twice: a map's mean already carries its runs'
noise, and redrawing the runs adds it again, so the bootstrap variance of a mean is about ``sigma_map^2 / M
+ (2 - 1/S) sigma_run^2 / (M S)`` for ``M`` maps of ``S`` runs, against the true ``sigma_map^2 / M +
sigma_run^2 / (M S)`` (nearly right when the maps differ much more than the runs on a map do; with no
map-level variance at all, ``sqrt(2 - 1/S)`` times wider than the run-level bootstrap). And with few maps it
is too narrow, as every percentile bootstrap over few units is: its variance carries the factor ``(M - 1) /
M``, and its quantiles are normal ones where Student's would hold. With 5 maps the second error wins (a
nominal 95% interval is an 87-93% one at the study's pilot variances); :func:`power` at no effect tells by
how much for a design.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
import scipy.stats

from dqn_transfer.analysis.stats import N_RESAMPLES, Estimate, improvement_by_task, no_interval, percentile_estimate

IQM_TRIM = 0.25  # rliable's IQM: scipy.stats.trim_mean(scores, 0.25), the mean of the middle 50%
POWER_SIMULATIONS = 20_000  # simulated studies per power: a power of 0.8 to within +-0.006 (2 s.e.)
MAX_MAPS = 4096  # the search for enough maps stops here (and says none is enough)
ValuesByMap = Sequence[Sequence[float] | np.ndarray]  # one array of run values per map
Statistic = Callable[[np.ndarray], np.ndarray]  # pooled runs [..., runs], nan-padded -> one value per row


@dataclass(frozen=True)
class MeanDifference:
    """mean(X - Y) with its hierarchical-bootstrap interval (``estimate``, whose ``n`` counts the maps) and
    the two-sided bootstrap p-value of "no difference" (:func:`bootstrap_p_value`)."""

    estimate: Estimate
    p_value: float


@dataclass(frozen=True)
class VarianceComponents:
    """A one-way random-effects decomposition of run values: ``value = mean + map effect + run noise``, the
    map effects with standard deviation ``sigma_map``, the run noise with ``sigma_run``; estimated from
    ``n_maps`` maps holding ``n_runs`` runs in all."""

    mean: float
    sigma_map: float
    sigma_run: float
    n_maps: int
    n_runs: int


# ------------------------------------------------------------------------------------------- statistics


def mean_of_runs(runs: np.ndarray) -> np.ndarray:
    """The mean of each row of pooled runs.

    :param runs: ``[..., runs]`` run values, ``nan`` where a resample holds no run.
    """
    return np.nanmean(runs, axis=-1)


def iqm_of_runs(runs: np.ndarray) -> np.ndarray:
    """The interquartile mean of each row of pooled runs, as rliable defines it
    (``scipy.stats.trim_mean(row, 0.25)``: ``int(0.25 k)`` values cut from each end of a row of ``k`` runs),
    computed for rows of different lengths at once.

    :param runs: ``[..., runs]`` run values, ``nan`` where a resample holds no run.
    """
    ordered = np.sort(runs, axis=-1)  # nan sorts last
    count = np.sum(~np.isnan(runs), axis=-1, keepdims=True)
    cut = np.floor(IQM_TRIM * count).astype(np.intp)
    place = np.arange(runs.shape[-1])
    kept = (place >= cut) & (place < count - cut)
    return np.where(kept, ordered, 0.0).sum(axis=-1) / kept.sum(axis=-1)


def fraction_below(runs: np.ndarray, threshold: float) -> np.ndarray:
    """The fraction of each row's runs whose value is below ``threshold`` (a failure rate).

    :param runs: ``[..., runs]`` run values, ``nan`` where a resample holds no run.
    :param threshold: a run below it failed (e.g. a final score under a bound).
    """
    present = ~np.isnan(runs)
    return np.sum(present & (runs < threshold), axis=-1) / present.sum(axis=-1)


# ------------------------------------------------------------------------------------------- resampling


def _padded(values_by_map: ValuesByMap) -> tuple[np.ndarray, np.ndarray]:
    """``(values [maps, widest], counts [maps])``: the maps' runs in one array, ``nan`` after a map's last."""
    arrays = [np.asarray(v, dtype=np.float64) for v in values_by_map]
    if not arrays or any(a.ndim != 1 or a.size == 0 for a in arrays):
        raise ValueError("values_by_map needs at least one map, each a non-empty 1-D array of run values")
    if not all(np.isfinite(a).all() for a in arrays):
        raise ValueError("run values must be finite (nan marks a missing run inside the bootstrap)")
    counts = np.array([a.size for a in arrays])
    values = np.full((len(arrays), counts.max()), np.nan)
    for row, array in zip(values, arrays):
        row[: array.size] = array
    return values, counts


def _draw_maps(n_maps: int, rng: np.random.Generator, n_resamples: int) -> np.ndarray:
    """``[resamples, maps]``: the first stage, map indices drawn with replacement."""
    return rng.integers(0, n_maps, size=(n_resamples, n_maps))


def _draw_runs(counts: np.ndarray, maps: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``[resamples, maps, widest]``: the second stage, run indices drawn with replacement within each drawn
    map (as many as it holds), -1 past them."""
    held = counts[maps][..., None]
    widest = int(counts.max())
    drawn = np.floor(rng.random((*maps.shape, widest)) * held).astype(np.intp)
    return np.where(np.arange(widest) < held, drawn, -1)


def _take(values: np.ndarray, maps: np.ndarray, runs: np.ndarray) -> np.ndarray:
    """``[resamples, maps, widest]``: the drawn runs' values, ``nan`` where no run was drawn."""
    return np.where(runs >= 0, values[maps[..., None], np.maximum(runs, 0)], np.nan)


def _pooled(resampled: np.ndarray) -> np.ndarray:
    """``[resamples, maps * widest]``: a resample's runs pooled over its maps."""
    return resampled.reshape(resampled.shape[0], -1)


def _resampled(
    values_by_map: ValuesByMap, statistic: Statistic, rng: np.random.Generator, n_resamples: int
) -> tuple[float, np.ndarray | None]:
    """The statistic of all runs pooled and its two-stage resamples ``[resamples]`` (None with one map)."""
    values, counts = _padded(values_by_map)
    point = float(statistic(values.reshape(1, -1))[0])
    if len(counts) < 2:
        return point, None
    maps = _draw_maps(len(counts), rng, n_resamples)
    return point, statistic(_pooled(_take(values, maps, _draw_runs(counts, maps, rng))))


def hierarchical_bootstrap(
    values_by_map: ValuesByMap,
    statistic: Statistic,
    rng: np.random.Generator,
    n_resamples: int = N_RESAMPLES,
    confidence: float = 0.95,
) -> Estimate:
    """A statistic of all runs pooled over maps, with its two-stage percentile-bootstrap interval (maps
    drawn with replacement, then runs within each drawn map). The :class:`Estimate`'s ``n`` counts the
    maps, the unit the interval speaks of; with a single map there is no interval (``nan``).

    :param values_by_map: one 1-D array of finite run values per map; maps may hold unequal numbers of runs.
    :param statistic: pooled runs ``[..., runs]`` (``nan``-padded) to one value per row: :func:`mean_of_runs`,
        :func:`iqm_of_runs`, ``functools.partial(fraction_below, threshold=...)``.
    :param rng: the resampling stream.
    :param n_resamples: bootstrap resamples.
    :param confidence: the interval's coverage, in (0, 1).
    """
    point, resampled = _resampled(values_by_map, statistic, rng, n_resamples)
    if resampled is None:
        return no_interval(point, len(values_by_map))
    return percentile_estimate(point, resampled, confidence, len(values_by_map))


def failure_rate(values_by_map: ValuesByMap, threshold: float, rng: np.random.Generator, **bootstrap: Any) -> Estimate:
    """The fraction of runs below ``threshold`` with its hierarchical interval, to report beside the IQM (which
    drops its worst quarter of runs by design).

    :param values_by_map: one 1-D array of finite run values per map.
    :param threshold: a run below it failed (e.g. a final success rate of 0: a small positive threshold).
    :param rng: the resampling stream.
    :param bootstrap: ``n_resamples`` and ``confidence``, as :func:`hierarchical_bootstrap` takes them.
    """
    return hierarchical_bootstrap(values_by_map, partial(fraction_below, threshold=threshold), rng, **bootstrap)


# --------------------------------------------------------------------------------- two conditions


def _same_maps(x_by_map: ValuesByMap, y_by_map: ValuesByMap, paired_seeds: bool) -> None:
    if len(x_by_map) != len(y_by_map):
        raise ValueError(f"x and y must hold the same maps: {len(x_by_map)} and {len(y_by_map)}")
    if paired_seeds and any(len(x) != len(y) for x, y in zip(x_by_map, y_by_map)):
        raise ValueError("paired_seeds needs the same runs (seeds), in the same order, on each map of x and y")


def bootstrap_p_value(resampled: np.ndarray, null: float = 0.0) -> float:
    """The two-sided p-value of ``null`` by inverting the percentile interval: the smallest ``alpha`` at
    which the ``1 - alpha`` percentile interval of ``resampled`` excludes ``null``, i.e. twice the smaller
    tail's share (each count plus one, so that no bootstrap gives p = 0). It rejects exactly when the
    intervals of the same resamples do, and :func:`holm` can adjust it.

    :param resampled: a statistic's bootstrap resamples.
    :param null: the value of the statistic under "no difference".
    """
    below = (np.count_nonzero(resampled <= null) + 1) / (resampled.size + 1)
    above = (np.count_nonzero(resampled >= null) + 1) / (resampled.size + 1)
    return float(min(1.0, 2.0 * min(below, above)))


def _difference(point: float, resampled: np.ndarray | None, confidence: float, n_maps: int) -> MeanDifference:
    """A difference with its interval and p-value from its resamples (None: one map, neither)."""
    if resampled is None:
        return MeanDifference(no_interval(point, n_maps), math.nan)
    return MeanDifference(percentile_estimate(point, resampled, confidence, n_maps), bootstrap_p_value(resampled))


def paired_mean_difference(
    differences_by_map: ValuesByMap,
    rng: np.random.Generator,
    n_resamples: int = N_RESAMPLES,
    confidence: float = 0.95,
) -> MeanDifference:
    """The mean of paired differences (X - Y of the same map and seed) with its hierarchical interval and
    p-value: the run pair is the unit within a map, so its difference is resampled as one value.

    :param differences_by_map: one 1-D array of paired differences per map.
    :param rng: the resampling stream.
    :param n_resamples: bootstrap resamples.
    :param confidence: the interval's coverage, in (0, 1).
    """
    point, resampled = _resampled(differences_by_map, mean_of_runs, rng, n_resamples)
    return _difference(point, resampled, confidence, len(differences_by_map))


def independent_mean_difference(
    x_by_map: ValuesByMap,
    y_by_map: ValuesByMap,
    rng: np.random.Generator,
    n_resamples: int = N_RESAMPLES,
    confidence: float = 0.95,
) -> MeanDifference:
    """mean(X) - mean(Y) for two conditions on different maps (two populations, e.g. high- and low-contention
    maps): each condition's maps and runs are resampled on their own. ``n`` counts the maps of both.

    :param x_by_map: condition X's run values, one 1-D array per map.
    :param y_by_map: condition Y's, on other maps.
    :param rng: the resampling stream.
    :param n_resamples: bootstrap resamples.
    :param confidence: the interval's coverage, in (0, 1).
    """
    (x, x_resampled), (y, y_resampled) = (_resampled(v, mean_of_runs, rng, n_resamples) for v in (x_by_map, y_by_map))
    resampled = None if x_resampled is None or y_resampled is None else x_resampled - y_resampled
    return _difference(x - y, resampled, confidence, len(x_by_map) + len(y_by_map))


def paired_slope(
    differences_by_size: dict[int, ValuesByMap],
    rng: np.random.Generator,
    n_resamples: int = N_RESAMPLES,
    confidence: float = 0.95,
) -> MeanDifference:
    """The least-squares slope over a size ``m`` (e.g. team size) of the mean paired difference at each ``m``,
    with its hierarchical interval and p-value of "no trend": within each ``m`` its own maps are drawn with
    replacement, then the paired differences within each drawn map (:func:`paired_mean_difference`'s two
    stages, independently for each ``m``, whose maps differ). ``n`` counts the maps over all sizes.

    :param differences_by_size: for each size, one 1-D array of paired differences per map.
    :param rng: the resampling stream.
    :param n_resamples: bootstrap resamples.
    :param confidence: the interval's coverage, in (0, 1).
    """
    sizes = np.array(sorted(differences_by_size), dtype=np.float64)
    if sizes.size < 2:
        raise ValueError(f"a slope needs two sizes or more, got {sizes.size}")
    centred = sizes - sizes.mean()
    drawn = [_resampled(differences_by_size[int(m)], mean_of_runs, rng, n_resamples) for m in sizes]
    point = float(centred @ np.array([mean for mean, _ in drawn]) / (centred @ centred))
    n_maps = sum(len(differences_by_size[int(m)]) for m in sizes)
    if any(resampled is None for _, resampled in drawn):
        return _difference(point, None, confidence, n_maps)
    means = np.stack([resampled for _, resampled in drawn if resampled is not None], axis=1)  # [resamples, m]
    slopes = (means - means.mean(axis=1, keepdims=True)) @ centred / (centred @ centred)
    return _difference(point, slopes, confidence, n_maps)


def mean_difference(
    x_by_map: ValuesByMap,
    y_by_map: ValuesByMap,
    rng: np.random.Generator,
    paired_seeds: bool,
    n_resamples: int = N_RESAMPLES,
    confidence: float = 0.95,
) -> MeanDifference:
    """mean(X) - mean(Y) over the pooled runs, with its hierarchical interval and p-value. Both conditions
    ran on the same maps, so a resample draws the maps once for both. Where the design also pairs them by
    seed (the same seed shares a map's initial values and exploration noise), the unit is the run pair
    (:func:`paired_mean_difference` of ``x - y``); otherwise each condition's runs are redrawn within each
    drawn map independently.

    :param x_by_map: condition X's run values, one 1-D array per map.
    :param y_by_map: condition Y's, the same maps in the same order.
    :param rng: the resampling stream.
    :param paired_seeds: whether ``x_by_map[m][j]`` and ``y_by_map[m][j]`` are the same seed.
    :param n_resamples: bootstrap resamples.
    :param confidence: the interval's coverage, in (0, 1).
    """
    _same_maps(x_by_map, y_by_map, paired_seeds)
    if paired_seeds:
        differences = [np.subtract(x, y, dtype=np.float64) for x, y in zip(x_by_map, y_by_map)]
        return paired_mean_difference(differences, rng, n_resamples, confidence)
    (x, x_counts), (y, y_counts) = _padded(x_by_map), _padded(y_by_map)
    point = float(np.nanmean(x) - np.nanmean(y))
    if len(x_counts) < 2:
        return _difference(point, None, confidence, len(x_counts))
    maps = _draw_maps(len(x_counts), rng, n_resamples)
    x_resampled = _pooled(_take(x, maps, _draw_runs(x_counts, maps, rng)))
    y_resampled = _pooled(_take(y, maps, _draw_runs(y_counts, maps, rng)))
    resampled = mean_of_runs(x_resampled) - mean_of_runs(y_resampled)
    return _difference(point, resampled, confidence, len(x_counts))


def probability_of_improvement(
    x_by_map: ValuesByMap,
    y_by_map: ValuesByMap,
    rng: np.random.Generator,
    paired_seeds: bool = False,
    n_resamples: int = N_RESAMPLES,
    confidence: float = 0.95,
) -> Estimate:
    """P(X > Y) as rliable defines it: within each map, the probability that a run of X scores higher than
    a run of Y (every pair of runs, a tie counting one half: the Mann-Whitney U over ``n_x n_y``), then the
    mean over maps; with its hierarchical interval (maps drawn once for both conditions, then runs within
    each drawn map: each condition's own, or the (x, y) pairs of a seed where ``paired_seeds``). 0.5 is no
    difference. Ranks only: a monotone transform of the values leaves it unchanged. ``n`` counts the maps.

    Its resolution is the design's, not the method's: a map with ``n_x`` and ``n_y`` runs gives P in steps of
    ``1 / (n_x n_y)`` (half that with ties), so a mean over ``M`` maps, the point or a resample's, moves in
    steps of ``1 / (M n_x n_y)``. The first edition's P fell on a 0.05 grid because 5 maps x 2 x 2 runs make
    20 comparisons; on those data this P lies on the same grid (its point is the same 0.25). The grid is
    the design's, ``1 / (M S^2)`` for ``M`` maps x ``S`` seeds, e.g. 1/180 for 20 maps x 3 seeds, and the
    interval's width is set by how P varies from map to map, not by the grid.

    :param x_by_map: condition X's run values, one 1-D array per map.
    :param y_by_map: condition Y's, the same maps in the same order.
    :param rng: the resampling stream.
    :param paired_seeds: whether ``x_by_map[m][j]`` and ``y_by_map[m][j]`` are the same seed, resampled together.
    :param n_resamples: bootstrap resamples.
    :param confidence: the interval's coverage, in (0, 1).
    """
    _same_maps(x_by_map, y_by_map, paired_seeds)
    (x, x_counts), (y, y_counts) = _padded(x_by_map), _padded(y_by_map)
    point = float(improvement_by_task(x, y).mean())
    if len(x_counts) < 2:
        return no_interval(point, len(x_counts))
    maps = _draw_maps(len(x_counts), rng, n_resamples)
    x_runs = _draw_runs(x_counts, maps, rng)
    y_runs = x_runs if paired_seeds else _draw_runs(y_counts, maps, rng)
    resampled = improvement_by_task(_take(x, maps, x_runs), _take(y, maps, y_runs)).mean(axis=-1)
    return percentile_estimate(point, resampled, confidence, len(x_counts))


def holm(p_values: Sequence[float] | np.ndarray) -> np.ndarray:
    """Holm's (1979) step-down adjustment of a family of p-values, in their given order: the ``i``-th
    smallest of ``m`` is multiplied by ``m - i + 1``, never below the adjusted one before it, capped at 1.
    Rejecting where an adjusted p-value is below ``alpha`` keeps the family-wise error rate at ``alpha``
    under any dependence between the comparisons (Bonferroni's guarantee, with more power).

    :param p_values: the family's p-values (the primary comparisons only, fixed before seeing data).
    """
    p = np.asarray(p_values, dtype=np.float64)
    order = np.argsort(p, kind="stable")
    scaled = p[order] * (p.size - np.arange(p.size))
    adjusted = np.empty_like(p)
    adjusted[order] = np.minimum(1.0, np.maximum.accumulate(scaled))
    return adjusted


# ------------------------------------------------------------------------------------------------ power


def variance_components(values_by_map: ValuesByMap) -> VarianceComponents:
    """Map-level and run-level standard deviations of run values, by the method of moments of one-way
    random-effects ANOVA (unequal runs per map allowed): ``sigma_run^2`` is the within-map mean square,
    ``sigma_map^2 = (MSB - MSW) / n0`` with ``n0 = (N - sum n_m^2 / N) / (M - 1)``, set to 0 when negative
    (the maps differ no more than their runs' noise explains).

    :param values_by_map: one 1-D array of finite run values per map (for a power analysis: pilot paired
        differences); at least two maps, and at least one map with two runs.
    """
    arrays = [np.asarray(v, dtype=np.float64) for v in values_by_map]
    counts = np.array([a.size for a in arrays])
    n_maps, n_runs = len(arrays), int(counts.sum())
    if n_maps < 2 or n_runs <= n_maps or np.any(counts == 0):
        raise ValueError("variance components need two maps or more, no empty map, and a map with two runs")
    means = np.array([a.mean() for a in arrays])
    grand = float(np.concatenate(arrays).mean())
    within = sum(float(((a - m) ** 2).sum()) for a, m in zip(arrays, means)) / (n_runs - n_maps)
    between = float((counts * (means - grand) ** 2).sum()) / (n_maps - 1)
    n0 = (n_runs - float((counts**2).sum()) / n_runs) / (n_maps - 1)
    return VarianceComponents(grand, math.sqrt(max(0.0, (between - within) / n0)), math.sqrt(within), n_maps, n_runs)


def two_stage_variance(
    between_ss: np.ndarray | float, within_ss: np.ndarray | float, n_maps: int, n_seeds: int
) -> np.ndarray | float:
    """The exact variance of the two-stage bootstrap's resampled mean, for ``n_maps`` maps of ``n_seeds``
    runs each: a drawn map's resampled mean varies by the spread of the map means (``between_ss / M``) plus
    its runs' own resampling variance (``within_ss / (M S^2)`` on average), and the ``M`` drawn maps are
    independent.

    :param between_ss: ``sum_m (mean_m - grand mean)^2`` over the maps.
    :param within_ss: ``sum_m sum_j (value_mj - mean_m)^2`` over every run.
    :param n_maps: ``M``.
    :param n_seeds: ``S``, runs per map.
    """
    return (between_ss / n_maps + within_ss / (n_maps * n_seeds**2)) / n_maps


def power(
    effect: float,
    sigma_map: float,
    sigma_run: float,
    n_maps: int,
    n_seeds: int,
    rng: np.random.Generator,
    alpha: float = 0.05,
    n_simulations: int = POWER_SIMULATIONS,
) -> float:
    """The probability that the hierarchical ``1 - alpha`` interval of a mean (paired) difference excludes 0,
    for a study of ``n_maps`` maps x ``n_seeds`` seeds whose differences follow the normal random-effects
    model ``effect + N(0, sigma_map^2) per map + N(0, sigma_run^2) per run``. With ``effect = 0`` it is the
    test's size (its false-positive rate), which exceeds ``alpha`` with few maps.

    Simulated, and fast: under the model a study's mean, its between-map and its within-map sums of squares
    are independent (a normal and two scaled chi-squares), which is all :func:`two_stage_variance` needs, so
    a simulated study costs three draws whatever its size. Its interval is the normal one at the bootstrap's
    exact variance (``tests/test_hierarchical.py`` checks it rejects as often as :func:`mean_difference`'s
    percentile interval does).

    :param effect: the true mean difference (the smallest effect of interest; 0 for the size).
    :param sigma_map: map-level standard deviation of the differences.
    :param sigma_run: run-level (seed) standard deviation of the differences.
    :param n_maps: maps in the study, at least 2.
    :param n_seeds: seeds per map, at least 1.
    :param rng: the simulation stream.
    :param alpha: the interval is ``1 - alpha``.
    :param n_simulations: simulated studies.
    """
    if n_maps < 2 or n_seeds < 1:
        raise ValueError(f"power needs two maps or more and a seed or more, got {n_maps} x {n_seeds}")
    map_mean_variance = sigma_map**2 + sigma_run**2 / n_seeds
    mean = effect + math.sqrt(map_mean_variance / n_maps) * rng.standard_normal(n_simulations)
    between_ss = map_mean_variance * rng.chisquare(n_maps - 1, n_simulations)
    within_ss = sigma_run**2 * rng.gamma((n_maps * (n_seeds - 1)) / 2.0, 2.0, n_simulations)  # chi2; 0 dof: 0
    half_width = scipy.stats.norm.ppf(1.0 - alpha / 2.0) * np.sqrt(
        two_stage_variance(between_ss, within_ss, n_maps, n_seeds)
    )
    return float(np.mean(np.abs(mean) > half_width))


def maps_for_power(
    effect: float,
    sigma_map: float,
    sigma_run: float,
    n_seeds: int,
    rng: np.random.Generator,
    target: float = 0.8,
    alpha: float = 0.05,
    n_simulations: int = POWER_SIMULATIONS,
) -> int | None:
    """The fewest maps (``n_seeds`` seeds each) whose :func:`power` reaches ``target``: doubling from 2 maps
    until it does, then bisecting (power grows with maps; near the answer, by less than the simulation's
    error, so the answer may be one or two maps off). ``None`` if :data:`MAX_MAPS` maps are not enough.

    :param effect: the smallest effect of interest, in the differences' units.
    :param sigma_map: map-level standard deviation of the differences.
    :param sigma_run: run-level (seed) standard deviation of the differences.
    :param n_seeds: seeds per map.
    :param rng: the simulation stream.
    :param target: the power wanted.
    :param alpha: the interval is ``1 - alpha``.
    :param n_simulations: simulated studies per power.
    """

    def reaches(n_maps: int) -> bool:
        return power(effect, sigma_map, sigma_run, n_maps, n_seeds, rng, alpha, n_simulations) >= target

    low, high = 1, 2  # low: known not enough (1 map has no interval); high: to test
    while not reaches(high):
        if high >= MAX_MAPS:
            return None
        low, high = high, min(2 * high, MAX_MAPS)
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (low, middle) if reaches(middle) else (middle, high)
    return high
