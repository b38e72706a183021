"""The ``torch`` engine of :class:`~dqn_transfer.agents.dqn_base.BatchedDQN`: any device; the DQN update stated once.

Read :meth:`DQNLearner.train_on`: CleanRL's ``dqn.py`` update, for all agents' networks at once (one
:class:`~dqn_transfer.agents.networks.BatchedMLP`): the target under ``torch.no_grad()``, the Huber loss,
``loss.backward()``, the gradient clip, ``torch.optim.Adam``'s step. Any new network or loss runs here
first; the ``numpy`` engine (:mod:`~dqn_transfer.agents.numpy_dqn`) is a CPU fast path for the losses it
implements, checked step for step against this one. The target and the loss are
:mod:`dqn_transfer.agents.dqn_update`'s; the schedule is :mod:`dqn_transfer.agents.dqn_base`'s. The replay
batch comes from the host and is moved to the device.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import torch

from dqn_transfer.agents.base import UpdateStats
from dqn_transfer.agents.dqn_base import BatchedDQN
from dqn_transfer.agents.dqn_update import double_dqn_targets, dqn_targets, huber, live_mean, td_losses, team_td_errors
from dqn_transfer.agents.networks import BatchedMLP
from dqn_transfer.agents.replay import ReplayBatch
from dqn_transfer.agents.stacked import FLUSH_EVERY, SMALLEST_NORMAL
from dqn_transfer.config import ConfigError
from dqn_transfer.enums import Device

# Relative lead of the best action's Q-value over the second best above which numpy's argmax is
# torch's: their float32 results differ by a few units in the 7th digit, this is 1000x that.
ACTION_MARGIN = 1e-4


def resolve_device(device: Device | str, threads: int | None = None) -> str:
    """``device`` (cpu | cuda | auto) as torch's device name; torch then uses ``threads`` CPU threads
    (None: leave them as they are)."""
    device = Device(device)
    if threads is not None:
        torch.set_num_threads(threads)
    if device is Device.auto:
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device is Device.cuda and not torch.cuda.is_available():
        raise ConfigError("device=cuda but no CUDA device is available here (use device=cpu or device=auto)")
    return device.value


class StackedAdam(torch.optim.Adam):
    """``torch.optim.Adam`` (foreach) over a :class:`~dqn_transfer.agents.networks.BatchedMLP`'s tensors, with
    the per-tensor state access :class:`~dqn_transfer.agents.dqn_base.BatchedDQN`'s checkpoints and transfer
    use (:class:`~dqn_transfer.agents.dqn_base.StackedOptimizer`): state ``i`` is tensor ``i``'s, shaped as it.

    :param network: the online networks
    :param lr: the step size
    """

    def __init__(self, network: BatchedMLP, lr: float) -> None:
        super().__init__(network.tensors, lr=lr, foreach=True)
        self.tensors = network.tensors

    @property
    def has_state(self) -> list[bool]:
        return [bool(self.state.get(tensor)) for tensor in self.tensors]

    def moments(self, i: int, shape: Sequence[int]) -> dict[str, Any]:
        state = self.state[self.tensors[i]]
        return {"exp_avg": state["exp_avg"], "exp_avg_sq": state["exp_avg_sq"]}

    def step_count(self, i: int) -> int:
        return int(self.state[self.tensors[i]]["step"])

    def set_step(self, i: int, step: int) -> None:
        tensor = self.tensors[i]
        state = self.state[tensor]
        if not state:  # the state torch.optim.Adam creates at a tensor's first step
            state.update(exp_avg=torch.zeros_like(tensor), exp_avg_sq=torch.zeros_like(tensor))
        state["step"] = torch.tensor(float(step))

    @torch.no_grad()
    def flush_subnormals(self) -> None:
        """Set moments below float32's smallest normal number to zero.

        A moment that stops receiving gradient (an input the agent no longer sees) decays towards zero
        and turns subnormal, and element-wise kernels run 10-15x slower on subnormal numbers. Such a
        moment is ~1e-38: its share of a weight's step is below that weight's last bit, so flushing it
        changes no weight.
        """
        for state in self.state.values():
            for key in ("exp_avg", "exp_avg_sq"):
                state[key].masked_fill_(state[key].abs() < SMALLEST_NORMAL, 0.0)


class DQNLearner(BatchedDQN):
    """:class:`~dqn_transfer.agents.dqn_base.BatchedDQN` in torch, on ``device``."""

    def __init__(self, *args: Any, device: torch.device | str = "cpu", **kwargs: Any) -> None:
        """The parameters are :class:`~dqn_transfer.agents.dqn_base.BatchedDQN`'s, and ``device``: where the
        networks live (the replay stays on the host)."""
        self.device = torch.device(device)
        self._device_weights: dict[str, tuple[np.ndarray, torch.Tensor]] = {}  # name: (host array, its device copy)
        super().__init__(*args, **kwargs)

    def _build_networks(self, num_actions: int) -> None:
        # Initial weights: torch's generator, on the CPU, so the seed gives the same weights on any device.
        generators = [torch.Generator().manual_seed(s) for s in self.seeds]
        self.q_network = BatchedMLP(self.num_members, self.obs_dim, self.hidden, num_actions, generators, self.device)
        self.target_network = BatchedMLP(self.num_members, self.obs_dim, self.hidden, num_actions, device=self.device)
        self.target_network.requires_grad_(False)
        self.target_network.update_from(self.q_network, tau=1.0)
        self.optimizer = StackedAdam(self.q_network, lr=self.lr)

    def _to_engine(self, array: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(array, device=self.device)

    def _to_numpy(self, array: torch.Tensor) -> np.ndarray:
        return array.cpu().numpy()

    # ------------------------------------------------------------------------------------ acting

    def _team_batch(self, obs: torch.Tensor) -> torch.Tensor:
        """``obs [rows, B, D]`` as the members' inputs: a shared network sees its replica's agents as
        one big batch."""
        if self.share_parameters:
            rows, b, d = obs.shape
            return obs.reshape(rows // self.num_agents, self.num_agents * b, d)
        return obs

    def _q_values(self, network: BatchedMLP, obs: torch.Tensor, replica: int | None = None) -> torch.Tensor:
        """``obs [rows, B, D] -> Q [rows, B, A]`` (rows of one replica, or of all)."""
        q_values = network(self._team_batch(obs), self._members(replica))
        return q_values.view(*obs.shape[:2], -1) if self.share_parameters else q_values

    @torch.no_grad()
    def _online_q_values(self, inputs: np.ndarray, replica: int | None) -> np.ndarray:
        inputs_t = torch.as_tensor(inputs, device=self.device)
        return self._q_values(self.q_network, inputs_t.unsqueeze(1), replica).squeeze(1).cpu().numpy()

    @torch.no_grad()
    def _greedy_actions(self, inputs: np.ndarray, replica: int | None) -> np.ndarray:
        """On the CPU the Q-values are first computed in numpy, several times cheaper for these tiny
        batches. numpy's kernels may differ from torch's in the last bits, which can only change an
        argmax whose best two values are that close: when every row's best action leads by more than
        ACTION_MARGIN, numpy's argmax is torch's; otherwise (a near-tie, e.g. fresh or copied weights)
        torch decides. The actions are exactly torch's either way.
        """
        q_values = self.q_network.predict_numpy(self._team_batch_numpy(inputs), self._members(replica))
        if q_values is not None:
            q_values = q_values.reshape(inputs.shape[0], -1)
            top_two = np.partition(q_values, -2, axis=-1)[:, -2:]
            if (top_two[:, 1] - top_two[:, 0] > ACTION_MARGIN * (1.0 + np.abs(top_two[:, 1]))).all():
                return q_values.argmax(axis=-1)
        inputs_t = torch.from_numpy(inputs).to(self.device).unsqueeze(1)
        return self._q_values(self.q_network, inputs_t, replica).argmax(dim=-1).view(-1).cpu().numpy()

    # ---------------------------------------------------------------------------------- learning

    def _on_device(self, name: str, weights: np.ndarray) -> torch.Tensor:
        """A cached host array of weights (:meth:`loss_weights`, ``SharedExperience.sample_weights``) on the
        device, copied there once per new host array."""
        copy = self._device_weights.get(name)
        if copy is None or copy[0] is not weights:
            copy = self._device_weights[name] = (weights, torch.from_numpy(weights).to(self.device))
        return copy[1]

    def freeze(self, layer_indices: Iterable[int]) -> None:
        super().freeze(layer_indices)
        for l in self.frozen_layers:  # no gradient, so Adam skips them (moments and step count kept)
            for tensor in self.q_network.layer(l):
                tensor.requires_grad_(False)

    def train_on(
        self, batch: ReplayBatch, sample_weights: np.ndarray | None = None, live: np.ndarray | None = None
    ) -> UpdateStats:
        """One Adam step for all agents on ``batch`` (``[rows, B, ...]``, numpy on the host).

        The loss is ``sum_rows weight[row] * mean_batch Huber(Q(s, a) - y)`` (``loss_weights``: each agent's
        gradient is its own network's; with ``sample_weights`` a weighted mean, ``td_losses``); with ``live``
        (VDN) ``sum_teams weight[team] * mean_batch Huber(Q_tot(s, a) - y_tot)``, each row reporting its team's.
        """
        obs, actions, rewards, next_obs, terminated = (torch.from_numpy(field).to(self.device) for field in batch)
        valid = self.replay.size > 0
        loss_weights = self._on_device("loss", self.loss_weights(valid))

        # The target: no gradient flows into it. DQN takes the target network's max over the next actions;
        # Double DQN lets the online network choose the action and the target network score it.
        with torch.no_grad():
            next_q_target = self._q_values(self.target_network, next_obs)
            if self.double:
                next_q_online = self._q_values(self.q_network, next_obs)
                td_target = double_dqn_targets(rewards, next_q_online, next_q_target, terminated, self.gamma)
            else:
                td_target = dqn_targets(rewards, next_q_target, terminated, self.gamma)

        # The loss: Huber between Q(s, a) and the target, each agent's batch mean, weighted over agents.
        q_taken = self._q_values(self.q_network, obs).gather(-1, actions.unsqueeze(-1)).squeeze(-1)  # [rows, B]
        error = q_taken - td_target
        if live is None:
            sample_weights_t = None if sample_weights is None else self._on_device("sample", sample_weights)
            agent_losses = td_losses(error, sample_weights_t)  # [rows]
            loss = (loss_weights * agent_losses).sum()
            q_mean = q_taken.mean(dim=1)
        else:  # VDN: one TD error per team, Q_tot - y_tot; a team's rows share its weight
            live_t = torch.from_numpy(live).to(self.device)
            team_losses = huber(team_td_errors(error, live_t, self.num_agents)).mean(dim=1)  # [teams]
            loss = (loss_weights[:: self.num_agents] * team_losses).sum()
            agent_losses = team_losses.repeat_interleave(self.num_agents)
            q_mean = live_mean(q_taken, live_t)

        # The step: gradient, each network's norm clipped to max_grad_norm (per agent, or per replica's
        # shared network: never one norm over all), Adam (frozen layers have no gradient and are skipped).
        self.optimizer.zero_grad()
        loss.backward()
        self.q_network.clip_grad_norm_(self.max_grad_norm)
        self.optimizer.step()
        self.num_gradient_steps += 1
        # Every FLUSH_EVERY Adam steps (a saved count, so a resumed or warm-started run flushes alike).
        layers = self.trainable_layers
        if layers and self.optimizer.step_count(2 * layers[0]) % FLUSH_EVERY == 0:
            self.optimizer.flush_subnormals()

        stats = torch.stack([agent_losses, q_mean]).detach().cpu().numpy()  # one transfer
        return UpdateStats(np.where(valid, stats[0], np.nan), np.where(valid, stats[1], np.nan))
