"""The DQN / Double DQN update's decisions, written once for both engines (numpy arrays and torch tensors alike).

The update itself is stated in :meth:`dqn_transfer.agents.dqn.DQNLearner.train_on` (CleanRL's ``dqn.py``
shape: autograd and ``torch.optim.Adam``)::

    td_target = r + gamma * max_a Q_target(s', a) * (1 - terminated)        (Double DQN: see below)
    loss      = mean_batch Huber(Q(s, a) - td_target)                        (smooth L1, beta = 1)
    loss.backward(); clip_grad_norm_(max_grad_norm); adam.step()

Here are the pieces the numpy engine (:mod:`~dqn_transfer.agents.numpy_dqn`, which derives the gradient by
hand and is checked step for step against the torch engine) shares with it: :func:`dqn_targets` /
:func:`double_dqn_targets` (with the termination mask), :func:`huber` (the loss, reduced by
:func:`td_losses`, optionally with per-sample weights), :func:`clip_coefficient` (the clip rule).

VDN (``agent.mixer=vdn``, Sunehag et al. 2018) trains a team on one TD error, ``Q_tot - y_tot`` with
``Q_tot`` the sum of the live agents' Q-values; the engines reuse each agent's own target above and sum
(:func:`team_td_errors`, :func:`live_mean`).

This module imports no torch (the numpy engine uses it and never imports torch).
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

Array = Any  # a numpy array or a torch tensor (every function below takes either and returns the same kind)


def _xp(array: Array) -> Any:
    """The array's namespace: numpy, or torch for a tensor (already imported if there is a tensor)."""
    return np if isinstance(array, np.ndarray) else sys.modules["torch"]


def _take_last(values: Array, index: Array) -> Array:
    """``values[..., index[...]]``: one entry of the last axis per leading position."""
    if isinstance(values, np.ndarray):
        return np.take_along_axis(values, index[..., None], -1)[..., 0]
    return values.gather(-1, index.unsqueeze(-1)).squeeze(-1)


def _bootstrap(rewards: Array, next_q: Array, terminated: Array, gamma: float) -> Array:
    """``r + gamma * next_q * (1 - terminated)``.

    Only termination (a chest or a trap: the episode really ended) cuts the bootstrap. A step truncated
    by the time limit still has a future, and is not marked terminated: the timeout rule, applied where
    the replay stores transitions (:mod:`~dqn_transfer.agents.replay`), as SB3's
    ``handle_timeout_termination``.
    """
    if isinstance(terminated, np.ndarray):
        terminated = terminated.astype(rewards.dtype, copy=False)
    else:
        terminated = terminated.to(rewards.dtype)
    return rewards + gamma * next_q * (1.0 - terminated)


def dqn_targets(rewards: Array, next_q_target: Array, terminated: Array, gamma: float) -> Array:
    """DQN's target ``y = r + gamma * max_a Q_target(s', a) * (1 - terminated)``.

    ``rewards``, ``terminated`` ``[..., B]``, ``next_q_target`` ``[..., B, A]``; ``gamma``: the discount
    (``agent.gamma``).
    """
    return _bootstrap(rewards, _xp(next_q_target).amax(next_q_target, -1), terminated, gamma)


def double_dqn_targets(
    rewards: Array, next_q_online: Array, next_q_target: Array, terminated: Array, gamma: float
) -> Array:
    """Double DQN's target ``y = r + gamma * Q_target(s', argmax_a Q_online(s', a)) * (1 - terminated)``.

    The online network picks the action and the target network scores it, which removes the
    overestimation of taking the max of one noisy estimate (van Hasselt et al., 2016). Ties go to the
    first best action.
    """
    next_actions = _xp(next_q_online).argmax(next_q_online, -1)
    return _bootstrap(rewards, _take_last(next_q_target, next_actions), terminated, gamma)


def huber(error: Array) -> Array:
    """The Huber loss of the TD error ``Q(s, a) - y`` (``smooth_l1_loss`` with ``beta = 1``), element-wise:
    ``error^2 / 2`` within 1 of zero, ``|error| - 1/2`` beyond (the same floats as ``smooth_l1_loss``)."""
    xp = _xp(error)
    magnitude = xp.abs(error)
    return xp.where(magnitude < 1.0, 0.5 * error * error, magnitude - 0.5)


def td_losses(error: Array, sample_weights: Array | None = None) -> Array:
    """Each row's loss ``[rows]``: the mean :func:`huber` of its batch ``error [rows, B]``, or with
    ``sample_weights`` ``[rows, B]`` (each row's summing to 1, or all 0) their weighted sum: the weighted
    mean of ``transfer.exchange=experience``, where a team-mate's sample weighs ``experience_lambda``
    times an own one (:mod:`~dqn_transfer.agents.shared_experience`)."""
    if sample_weights is None:
        return huber(error).mean(-1)
    return (huber(error) * sample_weights).sum(-1)


def team_td_errors(error: Array, live: Array, num_agents: int) -> Array:
    """VDN's TD error of each team ``[teams, B]``, from its agents' ``error = Q_k(s, a) - y_k`` ``[rows, B]``
    (rows ``team * K + k``, their own targets) and ``live`` ``[rows, B]`` (1 where agent k acted in the step):
    ``sum_k live_k * (Q_k(s, a) - y_k) = Q_tot(s, a) - (r_tot + gamma * sum_k live_k (1 - terminated_k)
    Q_k^target(s'_k, a*_k))``. An agent done before the step adds nothing (no Q-value, no reward); one that
    ended in it by termination adds its Q-value and reward but no next value; one truncated bootstraps."""
    rows, batch = error.shape
    return (error * live).reshape(rows // num_agents, num_agents, batch).sum(1)


def live_mean(values: Array, live: Array) -> Array:
    """Each row's mean of ``values`` ``[rows, B]`` over the samples where ``live`` ``[rows, B]`` is 1 (nan where
    none is): an agent's mean ``Q(s, a)`` over the steps it acted in."""
    count = live.sum(-1)
    return _xp(values).where(count > 0, (values * live).sum(-1) / count.clip(1.0, None), float("nan"))


def clip_coefficient(norms: Array, max_norm: float) -> Array:
    """What ``clip_grad_norm_`` multiplies the gradients by, given their norm(s): at most 1, so that a
    norm above ``max_norm`` (``agent.max_grad_norm``) becomes ``max_norm`` (``1e-6``: torch's guard)."""
    return _xp(norms).clip(max_norm / (norms + 1e-6), None, 1.0)
