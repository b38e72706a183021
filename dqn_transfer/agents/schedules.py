"""Exploration schedules."""

from __future__ import annotations

import numpy as np


def linear_schedules(start: np.ndarray, end: np.ndarray, duration: np.ndarray, t: float) -> np.ndarray:
    """Per element: a value moving linearly from ``start`` (t = 0) to ``end`` (t = ``duration``), then
    held at ``end`` (float64 arrays of one shape).

    Same shape as CleanRL's ``linear_schedule``, but clamped on the fraction rather than with
    ``max(.., end)``, so it also works for a rising schedule. A non-positive ``duration`` means
    "already decayed" (e.g. ``exploration_fraction = 0``), not a division by zero.
    """
    duration = np.asarray(duration, dtype=np.float64)
    positive = duration > 0
    fraction = np.where(positive, np.clip(t / np.where(positive, duration, 1.0), 0.0, 1.0), 1.0)
    return start + fraction * (np.asarray(end) - start)


def linear_schedule(start: float, end: float, duration: float, t: float) -> float:
    """:func:`linear_schedules` of one value."""
    return float(linear_schedules(np.array([float(start)]), np.array([float(end)]), np.array([duration]), t)[0])
