"""The ``torch`` engine of :class:`~dqn_transfer.agents.dqn_base.BatchedDQN` (the default): any device.

The networks are one :class:`~dqn_transfer.agents.networks.BatchedMLP`, trained without autograd by
its hand-written backward and :class:`~dqn_transfer.agents.adam.FlatAdam`, both bit-identical to
``loss.backward()`` and ``torch.optim.Adam`` (the tests check it; ``scripts/time_dqn_backward.py``
measures what they save: about 6 % of a step for 40 networks, a quarter for 4). The target, the loss
and its gradient and the clip rule are :mod:`dqn_transfer.agents.dqn_update`'s, whose
``reference_update`` states the algorithm; the schedule is :mod:`dqn_transfer.agents.dqn_base`'s.
The replay batch comes from the host and is moved to the device.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from dqn_transfer.agents.adam import FlatAdam
from dqn_transfer.agents.base import ObsLayout, UpdateStats
from dqn_transfer.agents.dqn_base import BatchedDQN
from dqn_transfer.agents.dqn_update import (
    double_dqn_targets,
    dqn_targets,
    live_mean,
    td_loss_grad,
    td_losses,
    team_loss_grad,
    team_losses,
    team_td_errors,
)
from dqn_transfer.agents.networks import BatchedMLP
from dqn_transfer.agents.replay import ReplayBatch
from dqn_transfer.config import AgentConfig, ConfigError
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


class DQNLearner(BatchedDQN):
    """:class:`~dqn_transfer.agents.dqn_base.BatchedDQN` in torch, on ``device``."""

    def __init__(
        self,
        num_agents: int,
        obs_layout: ObsLayout,
        num_actions: int,
        hp: AgentConfig | None = None,
        *,
        seed: int | Sequence[int] = 0,
        device: torch.device | str = "cpu",
    ) -> None:
        """The parameters are :class:`~dqn_transfer.agents.dqn_base.BatchedDQN`'s, and ``device``: where the
        networks live (the replay stays on the host)."""
        super().__init__(num_agents, obs_layout, num_actions, hp if hp is not None else AgentConfig(), seed)
        self.device = torch.device(device)
        # Initial weights: torch's generator, on the CPU, so the seed gives the same weights on any device.
        generators = [torch.Generator().manual_seed(s) for s in self.seeds]
        self.q_network = BatchedMLP(self.num_members, self.obs_dim, self.hidden, num_actions, generators, self.device)
        self.target_network = BatchedMLP(self.num_members, self.obs_dim, self.hidden, num_actions, device=self.device)
        self.target_network.update_from(self.q_network, tau=1.0)
        self.optimizer = FlatAdam(self.q_network.flat, self.q_network.flat_grad, self.q_network.spans, lr=self.lr)
        self._device_weights: dict[str, tuple[np.ndarray, torch.Tensor]] = {}  # name: (host array, its device copy)

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
        q_values = network.predict(self._team_batch(obs), self._members(replica))
        return q_values.view(*obs.shape[:2], -1) if self.share_parameters else q_values

    @torch.no_grad()
    def _online_q_values(self, inputs: np.ndarray, replica: int | None) -> np.ndarray:
        inputs_t = torch.as_tensor(inputs, device=self.device)
        return self._q_values(self.q_network, inputs_t.unsqueeze(1), replica).squeeze(1).cpu().numpy()

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

    def train_on(
        self, batch: ReplayBatch, sample_weights: np.ndarray | None = None, live: np.ndarray | None = None
    ) -> UpdateStats:
        """One Adam step for all agents on ``batch`` (``[rows, B, ...]``, numpy on the host):
        :func:`~dqn_transfer.agents.dqn_update.reference_update` for every network at once (with ``live``:
        :func:`~dqn_transfer.agents.dqn_update.reference_vdn_update` for every replica's team).

        The loss is ``sum_rows weight[row] * mean_batch Huber(Q(s, a) - y)`` (see ``loss_weights``);
        its gradient is taken by hand (``td_loss_grad``, then ``BatchedMLP.backward``).
        """
        obs, actions, rewards, next_obs, terminated = (torch.from_numpy(field).to(self.device) for field in batch)
        with torch.no_grad():
            next_q_target = self._q_values(self.target_network, next_obs)
            if self.double:
                next_q_online = self._q_values(self.q_network, next_obs)
                targets = double_dqn_targets(rewards, next_q_online, next_q_target, terminated, self.gamma)
            else:
                targets = dqn_targets(rewards, next_q_target, terminated, self.gamma)

            out, inputs = self.q_network.forward_cached(self._team_batch(obs))
            q_values = out.reshape(*obs.shape[:2], -1)
            actions = actions.unsqueeze(-1)
            q_taken = q_values.gather(-1, actions).squeeze(-1)  # Q(s, a) [rows, B]
            error = q_taken - targets
            valid = self.replay.size > 0
            loss_weights = self._on_device("loss", self.loss_weights(valid))

            # d loss / d Q(s, a), scattered onto the actions taken, then back through the network.
            if live is None:
                sample_weights_t = None if sample_weights is None else self._on_device("sample", sample_weights)
                agent_losses = td_losses(error, sample_weights_t)  # [rows]
                grad_taken = td_loss_grad(error, loss_weights, sample_weights_t)
                q_mean = q_taken.mean(dim=1)
            else:
                live_t = torch.from_numpy(live).to(self.device)
                team_error = team_td_errors(error, live_t, self.num_agents)
                agent_losses = team_losses(team_error, self.num_agents)
                grad_taken = team_loss_grad(team_error, live_t, loss_weights)
                q_mean = live_mean(q_taken, live_t)
            grad_q = torch.zeros_like(q_values).scatter_add_(-1, actions, grad_taken.unsqueeze(-1))
            layers = self.trainable_layers
            self.q_network.backward(inputs, self._team_batch(grad_q), layers)
            self.q_network.clip_grad_norm_(self.max_grad_norm, layers)
            self.optimizer.step([2 * l + kind for l in layers for kind in (0, 1)])
            self.num_gradient_steps += 1

            stats = torch.stack([agent_losses, q_mean]).cpu().numpy()  # one transfer
        return UpdateStats(np.where(valid, stats[0], np.nan), np.where(valid, stats[1], np.nan))
