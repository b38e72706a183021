"""The DQN update of one plain ``nn.Sequential`` network, and VDN's of one team's networks, with autograd and
``torch.optim.Adam``: what the tests expect of both engines, which take it for all agents' stacked networks
at once (``DQNLearner.train_on`` states the same in the package; these are written per network, independently
of the stacking, the loss weights and the per-member clip).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F

from dqn_transfer.agents.dqn_update import double_dqn_targets, dqn_targets


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
