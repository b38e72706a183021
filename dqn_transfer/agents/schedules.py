"""Exploration schedules."""

from __future__ import annotations


def linear_schedule(start: float, end: float, duration: float, t: float) -> float:
    """Value moving linearly from ``start`` (t = 0) to ``end`` (t = duration), then held at ``end``.

    Same shape as CleanRL's ``linear_schedule``, but clamped on the fraction rather than with
    ``max(.., end)``, so it also works for a rising schedule. A non-positive ``duration`` means
    "already decayed" (e.g. ``exploration_fraction = 0``), not a division by zero.
    """
    if duration <= 0:
        return float(end)
    fraction = min(max(t / duration, 0.0), 1.0)
    return float(start + fraction * (end - start))
