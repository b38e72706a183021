"""The DQN / Double DQN update, in one place: the target, the loss, the clip and the Adam step.

Read :func:`reference_update` top to bottom: it is the algorithm, CleanRL's ``dqn.py`` update for one
network in plain torch with autograd and ``torch.optim.Adam``::

    td_target = r + gamma * max_a Q_target(s', a) * (1 - terminated)        (Double DQN: see below)
    loss      = mean_batch Huber(Q(s, a) - td_target)                        (smooth L1, beta = 1)
    loss.backward(); clip_grad_norm_(max_grad_norm); adam.step()

The engines (:mod:`~dqn_transfer.agents.dqn` in torch, :mod:`~dqn_transfer.agents.numpy_dqn` in numpy)
run the same update for all R x K agents at once with hand-written backward passes and a flat Adam,
which is what makes them fast; the tests (``tests/test_dqn_update.py``) check each engine's loss,
gradients and updated weights against :func:`reference_update` on the same weights and batch. The
algorithm's decisions the engines need are the functions above it, array-generic (numpy arrays and
torch tensors alike) and written once: :func:`dqn_targets` / :func:`double_dqn_targets` (with the
termination mask), :func:`huber` and :func:`huber_grad` (the loss and its derivative, reduced by
:func:`td_losses` and :func:`td_loss_grad`, optionally with per-sample weights), :func:`clip_coefficient`
(the clip rule). An engine keeps only numeric kernels: forward and backward matrix products, the gradient
norms, Adam's arithmetic.

VDN (``agent.mixer=vdn``, Sunehag et al. 2018) trains a team on one TD error, ``Q_tot - y_tot`` with
``Q_tot`` the sum of the live agents' Q-values: :func:`reference_vdn_update` states it in autograd, and
the engines reuse each agent's own target above and sum (:func:`team_td_errors`, :func:`team_losses`,
:func:`team_loss_grad`, :func:`live_mean`).

This module imports no torch at import time (the numpy engine uses it and never imports torch);
:func:`reference_update` and :func:`reference_vdn_update` import torch when called.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import torch

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


def huber_grad(error: Array) -> Array:
    """d :func:`huber` / d error: the TD error clipped to ``[-1, 1]``."""
    return _xp(error).clip(error, -1.0, 1.0)


def td_losses(error: Array, sample_weights: Array | None = None) -> Array:
    """Each row's loss ``[rows]``: the mean :func:`huber` of its batch ``error [rows, B]``, or with
    ``sample_weights`` ``[rows, B]`` (each row's summing to 1, or all 0) their weighted sum: the weighted
    mean of ``transfer.exchange=experience``, where a team-mate's sample weighs ``experience_lambda``
    times an own one (:mod:`~dqn_transfer.agents.shared_experience`)."""
    if sample_weights is None:
        return huber(error).mean(-1)
    return (huber(error) * sample_weights).sum(-1)


def td_loss_grad(error: Array, weights: Array, sample_weights: Array | None = None) -> Array:
    """d loss / d ``Q(s, a)`` ``[rows, B]`` for the engines' loss ``sum_rows weights[row] *
    td_losses(error, sample_weights)[row]`` (``weights`` ``[rows]``: see ``BatchedDQN.loss_weights``)."""
    if sample_weights is None:
        return huber_grad(error) * (weights[:, None] / error.shape[-1])
    return huber_grad(error) * (weights[:, None] * sample_weights)


def team_td_errors(error: Array, live: Array, num_agents: int) -> Array:
    """VDN's TD error of each team ``[teams, B]``, from its agents' ``error = Q_k(s, a) - y_k`` ``[rows, B]``
    (rows ``team * K + k``, their own targets) and ``live`` ``[rows, B]`` (1 where agent k acted in the step):
    ``sum_k live_k * (Q_k(s, a) - y_k) = Q_tot(s, a) - (r_tot + gamma * sum_k live_k (1 - terminated_k)
    Q_k^target(s'_k, a*_k))``. An agent done before the step adds nothing (no Q-value, no reward); one that
    ended in it by termination adds its Q-value and reward but no next value; one truncated bootstraps."""
    rows, batch = error.shape
    return (error * live).reshape(rows // num_agents, num_agents, batch).sum(1)


def team_losses(team_error: Array, num_agents: int) -> Array:
    """Each agent's row ``[rows]``: its team's loss, the mean :func:`huber` of its :func:`team_td_errors`."""
    losses = huber(team_error).mean(-1)
    if isinstance(losses, np.ndarray):
        return np.repeat(losses, num_agents)
    return losses.repeat_interleave(num_agents)


def team_loss_grad(team_error: Array, live: Array, weights: Array) -> Array:
    """d loss / d ``Q_k(s, a)`` ``[rows, B]`` for VDN's loss ``sum_teams weights[team] * mean_b
    huber(team_error)``: every agent live in a sample gets its team's gradient there (d Q_tot / d Q_k = 1),
    the others none. ``weights`` ``[rows]`` is the same for a team's rows (see ``BatchedDQN.loss_weights``)."""
    teams, batch = team_error.shape
    k = live.shape[0] // teams
    grad = huber_grad(team_error)[:, None, :] * live.reshape(teams, k, batch) * (weights.reshape(teams, k, 1) / batch)
    return grad.reshape(teams * k, batch)


def live_mean(values: Array, live: Array) -> Array:
    """Each row's mean of ``values`` ``[rows, B]`` over the samples where ``live`` ``[rows, B]`` is 1 (nan where
    none is): an agent's mean ``Q(s, a)`` over the steps it acted in."""
    count = live.sum(-1)
    return _xp(values).where(count > 0, (values * live).sum(-1) / count.clip(1.0, None), float("nan"))


def clip_coefficient(norms: Array, max_norm: float) -> Array:
    """What ``clip_grad_norm_`` multiplies the gradients by, given their norm(s): at most 1, so that a
    norm above ``max_norm`` (``agent.max_grad_norm``) becomes ``max_norm`` (``1e-6``: torch's guard)."""
    return _xp(norms).clip(max_norm / (norms + 1e-6), None, 1.0)


def reference_update(
    q_network: torch.nn.Module,
    target_network: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    batch: tuple[torch.Tensor, ...],
    weights: torch.Tensor,
    *,
    gamma: float,
    double: bool,
    max_grad_norm: float,
    sample_weights: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """One gradient step of one Q-network (an ``nn.Module`` and its Adam), with autograd: the algorithm.

    ``batch`` is ``(obs [n, B, D], actions [n, B], rewards [n, B], next_obs [n, B, D], terminated [n, B])``
    for the n agents the network serves: one for an agent's own network, a replica's K with
    ``share_parameters``. ``weights`` ``[n]`` is each agent's share of the loss (``loss_weights``: 1 for
    its own network, 1/K for a shared one, 0 for an agent with no data yet). ``optimizer`` is
    ``torch.optim.Adam(q_network.parameters(), lr=agent.lr)`` (torch's defaults otherwise); a parameter
    that does not require a gradient (a frozen layer) is neither clipped nor stepped. ``sample_weights``
    ``[n, B]`` (``transfer.exchange=experience``) makes each agent's loss the weighted mean of its batch
    instead of the plain mean (each row sums to 1). Returns each agent's loss and mean ``Q(s, a)`` ``[n]``.

    The engines take this step for every network at once; the gradient clip is per network (per agent,
    or per replica's shared network), never over all of them together.
    """
    import torch
    import torch.nn.functional as F

    obs, actions, rewards, next_obs, terminated = batch

    # The target: no gradient flows into it. DQN takes the target network's max over the next actions;
    # Double DQN lets the online network choose the action and the target network score it.
    with torch.no_grad():
        next_q_target = target_network(next_obs)
        if double:
            td_target = double_dqn_targets(rewards, q_network(next_obs), next_q_target, terminated, gamma)
        else:
            td_target = dqn_targets(rewards, next_q_target, terminated, gamma)

    # The loss: Huber between Q(s, a) and the target, averaged over each agent's batch, weighted over agents.
    q_taken = q_network(obs).gather(-1, actions.unsqueeze(-1)).squeeze(-1)
    sample_losses = F.smooth_l1_loss(q_taken, td_target, reduction="none")
    if sample_weights is None:
        agent_losses = sample_losses.mean(dim=-1)
    else:
        agent_losses = (sample_weights * sample_losses).sum(dim=-1)
    loss = (weights * agent_losses).sum()

    # The step: gradient, its norm clipped to max_grad_norm (agent.max_grad_norm), Adam.
    optimizer.zero_grad()
    loss.backward()
    torch.nn.utils.clip_grad_norm_(q_network.parameters(), max_grad_norm)
    optimizer.step()
    return agent_losses.detach(), q_taken.detach().mean(dim=-1)


def reference_vdn_update(
    q_networks: Sequence[torch.nn.Module],
    target_networks: Sequence[torch.nn.Module],
    optimizers: Sequence[torch.optim.Optimizer],
    batch: tuple[torch.Tensor, ...],
    live: torch.Tensor,
    *,
    gamma: float,
    double: bool,
    max_grad_norm: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """One gradient step of a team's VDN loss (``agent.mixer=vdn``, Sunehag et al. 2018), with autograd.

    ``batch`` is ``(obs [K, B, D], actions [K, B], rewards [K, B], next_obs [K, B, D], terminated [K, B])``,
    the same B joint steps for the team's K agents, and ``live`` ``[K, B]`` 1 where agent k acted in the
    step. ``q_networks[k]`` / ``target_networks[k]`` are agent k's networks (the same module for every k
    with ``share_parameters``); ``optimizers`` one ``torch.optim.Adam`` per distinct online network::

        Q_tot     = sum_k live_k Q_k(s_k, a_k)
        td_target = sum_k live_k r_k + gamma * sum_k live_k (1 - terminated_k) Q_k^target(s'_k, a*_k)
        loss      = mean_batch Huber(Q_tot - td_target)

    with ``a*_k`` the target network's best action (DQN) or the online network's (Double DQN). An agent
    done before the step is not live: it adds neither a Q-value nor a reward. The team's episode ends
    (no bootstrap at all) when every live agent terminates; a truncated agent still bootstraps (the
    timeout rule). Each network's gradient norm is clipped at ``max_grad_norm``, then every optimizer
    steps. Returns the team's loss and each agent's mean ``Q(s, a)`` over the steps it acted in ``[K]``.
    """
    import torch
    import torch.nn.functional as F

    obs, actions, rewards, next_obs, terminated = batch
    agents = range(len(q_networks))
    with torch.no_grad():
        next_q_target = torch.stack([target_networks[k](next_obs[k]) for k in agents])
        if double:
            best = torch.stack([q_networks[k](next_obs[k]) for k in agents]).argmax(-1, keepdim=True)
            next_value = next_q_target.gather(-1, best).squeeze(-1)
        else:
            next_value = next_q_target.amax(-1)
        td_target = (live * rewards).sum(0) + gamma * (live * (1.0 - terminated) * next_value).sum(0)

    q_taken = torch.stack([q_networks[k](obs[k]).gather(-1, actions[k].unsqueeze(-1)).squeeze(-1) for k in agents])
    loss = F.smooth_l1_loss((live * q_taken).sum(0), td_target)

    for optimizer in optimizers:
        optimizer.zero_grad()
    loss.backward()
    for network in {id(network): network for network in q_networks}.values():
        torch.nn.utils.clip_grad_norm_(network.parameters(), max_grad_norm)
    for optimizer in optimizers:
        optimizer.step()
    q_taken = q_taken.detach()
    return loss.detach(), (live * q_taken).sum(-1) / live.sum(-1)
