"""DQN and Double DQN for a team of K agents, batched into one network module and one optimizer.

The algorithm is CleanRL's ``dqn.py`` per agent (read ``DQNLearner.update`` top to bottom):
store the transition; every ``train_freq`` env steps after ``learning_starts``, take
``gradient_steps`` steps of Huber loss between ``Q(s, a)`` and the bootstrapped target on a uniform
replay batch (Adam, gradient-norm clip); every ``target_update`` env steps move the target network
``tau`` of the way to the online one (``tau == 1``: a hard copy) — the same rule as SB3's
``target_update_interval``/``tau`` and CleanRL's ``target_network_frequency``/``tau``.

What is particular here: all K agents are one ``BatchedMLP`` (stacked weights), their replay is one
``[K, capacity, ...]`` storage, and one Adam step updates everyone. The loss is the *sum* of the
agents' mean losses, so each agent's gradient is exactly the one its own network would get, and
gradients are clipped per agent. With ``share_parameters`` the team shares one network instead (the
parameter-sharing baseline): a single member whose forward pass serves all agents, replay still per
agent, loss the *mean* over agents.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from dqn_transfer.agents.base import ObsLayout, TeamShape, Transition, UpdateStats, epsilon_greedy
from dqn_transfer.agents.networks import BatchedMLP
from dqn_transfer.agents.replay import ReplayBuffer
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm


def dqn_targets(
    rewards: torch.Tensor, next_q_target: torch.Tensor, terminated: torch.Tensor, gamma: float
) -> torch.Tensor:
    """``y = r + gamma * max_a Q_target(s', a) * (1 - terminated)``.

    Only termination cuts the bootstrap: a truncated episode (time limit) still has a future.
    """
    return rewards + gamma * next_q_target.max(dim=-1).values * (1.0 - terminated.float())


def double_dqn_targets(
    rewards: torch.Tensor,
    next_q_online: torch.Tensor,
    next_q_target: torch.Tensor,
    terminated: torch.Tensor,
    gamma: float,
) -> torch.Tensor:
    """``y = r + gamma * Q_target(s', argmax_a Q_online(s', a)) * (1 - terminated)``.

    The online network picks the action and the target network scores it, which removes the
    overestimation of taking the max of one noisy estimate (van Hasselt et al., 2016).
    """
    next_actions = next_q_online.argmax(dim=-1, keepdim=True)
    next_q = next_q_target.gather(-1, next_actions).squeeze(-1)
    return rewards + gamma * next_q * (1.0 - terminated.float())


class DQNLearner(TeamShape):
    """K DQN / Double DQN agents (see the module docstring). Implements ``Learner``."""

    def __init__(
        self,
        num_agents: int,
        obs_layout: ObsLayout,
        num_actions: int,
        hp: AgentConfig = AgentConfig(),
        *,
        seed: int = 0,
        device: torch.device | str = "cpu",
    ) -> None:
        """
        :param num_agents: K, the agents of the team (each its own network unless ``share_parameters``)
        :param obs_layout: the observation's named segments ``[(name, size), ...]``
        :param num_actions: A, the discrete actions
        :param hp: the hyperparameters, documented on :class:`~dqn_transfer.config.AgentConfig` (their
            one home, shared with the command line); ``hp.algorithm`` picks the DQN or Double DQN target
        :param seed: fixes the initial weights, exploration and replay sampling
        :param device: where the networks and the replay storage live
        """
        algorithm = Algorithm(hp.algorithm)
        if algorithm.is_tabular:
            raise ValueError(f"DQNLearner trains the DQN family, not {algorithm.value}")
        super().__init__(algorithm, num_agents, obs_layout, num_actions)
        self.double = algorithm is Algorithm.double_dqn
        self.lr = hp.lr
        self.gamma = hp.gamma
        self.batch_size = hp.batch_size
        self.learning_starts = hp.learning_starts
        self.train_freq = hp.train_freq
        self.gradient_steps = hp.gradient_steps
        self.target_update = hp.target_update
        self.tau = hp.tau
        self.hidden = [int(h) for h in hp.hidden]
        self.max_grad_norm = hp.max_grad_norm
        self.share_parameters = hp.share_parameters
        self.device = torch.device(device)

        # Independent random streams: weights (torch, CPU so the seed gives the same weights on
        # any device), exploration and replay sampling (numpy, their states are JSON-able).
        init_generator = torch.Generator().manual_seed(seed)
        explore_seed, replay_seed = np.random.SeedSequence(seed).spawn(2)
        self.rng = np.random.default_rng(explore_seed)

        num_members = 1 if self.share_parameters else num_agents
        self.q_network = BatchedMLP(num_members, self.obs_dim, self.hidden, num_actions, init_generator)
        self.q_network.to(self.device)
        self.target_network = BatchedMLP(num_members, self.obs_dim, self.hidden, num_actions).to(self.device)
        self.target_network.update_from(self.q_network, tau=1.0)
        self.target_network.requires_grad_(False)
        self.frozen_layers: list[int] = []
        self.optimizer = torch.optim.Adam(self.q_network.parameters(), lr=self.lr)
        self.replay = ReplayBuffer(
            num_agents, hp.buffer_size, self.obs_dim, np.random.default_rng(replay_seed), self.device
        )
        self.num_gradient_steps = 0

    # ------------------------------------------------------------------------------------ acting

    def _q_values(self, network: BatchedMLP, obs: torch.Tensor) -> torch.Tensor:
        """``obs [K, B, D] -> Q [K, B, A]``; a shared network sees all agents as one big batch."""
        if self.share_parameters:
            k, b, d = obs.shape
            return network(obs.reshape(1, k * b, d)).reshape(k, b, -1)
        return network(obs)

    @torch.no_grad()
    def act(self, obs: np.ndarray, live: np.ndarray, epsilon: float | np.ndarray, greedy: bool = False) -> np.ndarray:
        """Per-agent epsilon-greedy; one forward pass for the whole team, skipped if everyone explores.

        Actions are returned for every agent; those of non-live agents are ignored by the game.
        """
        obs = np.asarray(obs, dtype=np.float32)
        if greedy:
            return self._greedy_actions(obs)
        # The exploration draws come first, from the shared epsilon_greedy (the same draws, so the same
        # random stream): given -1 as every greedy action, it returns -1 exactly where the agent exploits.
        actions = epsilon_greedy(np.full(obs.shape[0], -1, dtype=np.int64), epsilon, self.num_actions, self.rng)
        exploit = actions < 0
        if exploit.any():
            np.copyto(actions, self._greedy_actions(obs), where=exploit)
        return actions

    @torch.no_grad()
    def q_values(self, obs: np.ndarray) -> np.ndarray:
        """Each agent's online Q-values of its own observation: ``obs [K, D] -> [K, A]``."""
        obs_t = torch.as_tensor(np.asarray(obs, dtype=np.float32), device=self.device)
        return self._q_values(self.q_network, obs_t.unsqueeze(1)).squeeze(1).cpu().numpy()

    def _greedy_actions(self, obs: np.ndarray) -> np.ndarray:
        """``argmax_a Q(obs, a)`` per agent, ``obs`` float32 ``[K, D]``."""
        obs_t = torch.as_tensor(obs, device=self.device)
        q_values = self._q_values(self.q_network, obs_t.unsqueeze(1)).squeeze(1)
        return q_values.argmax(dim=-1).cpu().numpy().astype(np.int64, copy=False)

    # ---------------------------------------------------------------------------------- learning

    def update(self, transition: Transition, step: int) -> UpdateStats:
        """Store the live agents' transitions, train on schedule, sync the target on schedule.

        ``step`` counts env steps including this one. The statistics are averaged over this
        round's gradient steps (``q_mean``: mean ``Q(s, a)`` of the batch), nan if no training.
        """
        self.replay.add(transition)

        td_loss = np.full(self.num_agents, np.nan)
        q_mean = np.full(self.num_agents, np.nan)
        if step > self.learning_starts and step % self.train_freq == 0:
            rounds = [self.gradient_step() for _ in range(self.gradient_steps)]
            td_loss = np.mean([r.td_loss for r in rounds], axis=0, dtype=np.float64)
            q_mean = np.mean([r.q_mean for r in rounds], axis=0, dtype=np.float64)

        if step % self.target_update == 0:
            self.target_network.update_from(self.q_network, tau=self.tau)
        return UpdateStats(td_loss, q_mean)

    def gradient_step(self) -> UpdateStats:
        """One Adam step for all agents on a fresh replay batch (what ``update`` runs on schedule)."""
        batch = self.replay.sample(self.batch_size)
        with torch.no_grad():
            next_q_target = self._q_values(self.target_network, batch.next_obs)
            if self.double:
                next_q_online = self._q_values(self.q_network, batch.next_obs)
                targets = double_dqn_targets(batch.rewards, next_q_online, next_q_target, batch.terminated, self.gamma)
            else:
                targets = dqn_targets(batch.rewards, next_q_target, batch.terminated, self.gamma)

        q_values = self._q_values(self.q_network, batch.obs)
        q_taken = q_values.gather(-1, batch.actions.unsqueeze(-1)).squeeze(-1)  # Q(s, a) [K, B]
        agent_losses = F.smooth_l1_loss(q_taken, targets, reduction="none").mean(dim=1)  # [K]
        valid = self.replay.size > 0  # an empty agent's batch is placeholders: no loss
        if not valid.all():
            valid_t = torch.from_numpy(valid).to(self.device)
            agent_losses = torch.where(valid_t, agent_losses, torch.zeros_like(agent_losses))
        # Sum: each agent's gradient is its own loss's. Shared network: mean, the usual batch average.
        loss = agent_losses.sum() / max(int(valid.sum()), 1) if self.share_parameters else agent_losses.sum()

        self.optimizer.zero_grad()
        loss.backward()
        self.q_network.clip_grad_norm_(self.max_grad_norm)
        self.optimizer.step()
        self.num_gradient_steps += 1

        stats = torch.stack([agent_losses.detach(), q_taken.detach().mean(dim=1)]).cpu().numpy()  # one transfer
        return UpdateStats(np.where(valid, stats[0], np.nan), np.where(valid, stats[1], np.nan))

    # ------------------------------------------------------------------ transfer and exchange

    def freeze(self, layer_indices: Iterable[int]) -> None:
        """Keep these layers' weights and biases fixed (negative indices count from the output).

        The weights of a layer are one stacked Parameter for all agents, so freezing applies to the
        whole team. A frozen Parameter gets no gradient, and Adam skips parameters without one, so
        not even leftover momentum moves it.
        """
        layers = [range(self.q_network.num_layers)[index] for index in layer_indices]  # IndexError if absent
        for l in layers:
            for parameter in self.q_network.layer(l):
                parameter.requires_grad_(False)
        self.frozen_layers = sorted({*self.frozen_layers, *layers})

    def set_member_optimizer_state(self, i: int, moments: dict[str, dict[str, np.ndarray]], step: int) -> None:
        """Adam moments for agent i's slice of each stacked parameter, e.g. carried over by transfer.

        ``moments[name]`` holds ``exp_avg`` and ``exp_avg_sq`` shaped like one member's slice of
        parameter ``name``. Adam keeps one ``step`` per stacked parameter, shared by all agents.
        """
        m = self._member(i)
        for name, parameter in self.q_network.named_parameters():
            if name not in moments:  # e.g. a layer the source kept frozen has no moments
                continue
            state = self.optimizer.state[parameter]
            if not state:  # what Adam would create at its first step
                state["step"] = torch.tensor(0.0)
                state["exp_avg"] = torch.zeros_like(parameter, memory_format=torch.preserve_format)
                state["exp_avg_sq"] = torch.zeros_like(parameter, memory_format=torch.preserve_format)
            for key in ("exp_avg", "exp_avg_sq"):
                state[key][m] = torch.as_tensor(moments[name][key], device=self.device)
            state["step"] = torch.tensor(float(step))

    def _member(self, i: int) -> int:
        if not 0 <= i < self.num_agents:
            raise IndexError(f"agent index {i} out of range for {self.num_agents} agents")
        return 0 if self.share_parameters else i

    def add_experience(self, i: int, obs: np.ndarray, actions: np.ndarray, rewards: np.ndarray,
                       next_obs: np.ndarray, terminated: np.ndarray) -> None:
        """Append ``[N, ...]`` transitions (e.g. a team-mate's) to agent i's replay row."""
        self.replay.extend(i, obs, actions, rewards, next_obs, terminated)

    def get_member_weights(self, i: int) -> dict[str, torch.Tensor]:
        """Agent i's online network, ``layers.{l}.weight`` ``[out, in]`` / ``layers.{l}.bias``."""
        return self.q_network.member_state(self._member(i))

    def set_member_weights(self, i: int, tensors: dict[str, torch.Tensor]) -> None:
        """Overwrite agent i's online network (the target follows at its next sync)."""
        self.q_network.load_member_state(self._member(i), tensors)

    # -------------------------------------------------------------------------- checkpoints

    def agent_tensors(self, i: int) -> dict[str, torch.Tensor]:
        """``q.layers.{l}.weight|bias`` (online) and ``target.layers.{l}.weight|bias``.

        With ``share_parameters`` every agent returns the one shared network.
        """
        m = self._member(i)
        tensors = {f"q.{name}": t for name, t in self.q_network.member_state(m).items()}
        tensors.update({f"target.{name}": t for name, t in self.target_network.member_state(m).items()})
        return tensors

    def load_agent_tensors(self, i: int, tensors: dict[str, torch.Tensor]) -> None:
        """Load ``q.*`` and, if present, ``target.*`` (else the target becomes a copy of ``q.*``).

        With ``share_parameters`` all agents load into the one shared network: the last load wins.
        """
        m = self._member(i)
        online = {name[2:]: t for name, t in tensors.items() if name.startswith("q.")}
        target = {name[7:]: t for name, t in tensors.items() if name.startswith("target.")}
        self.q_network.load_member_state(m, online, name_prefix="q.")
        self.target_network.load_member_state(m, target or online, name_prefix="target." if target else "q.")

    def network_meta(self) -> dict[str, Any]:
        return {
            "obs_dim": self.obs_dim,
            "num_actions": self.num_actions,
            "hidden": list(self.hidden),
            "activation": "relu",
            "share_parameters": self.share_parameters,
        }

    def training_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Adam moments (by parameter name), replay storage and pointers, RNG states, counters.

        The network weights themselves are in ``agent_tensors``: resume = ``load_agent_tensors``
        for every agent, then ``load_training_state``.
        """
        arrays = {f"replay.{name}": value for name, value in self.replay.state_dict().items()}
        names = {id(p): name for name, p in self.q_network.named_parameters()}
        for parameter, state in self.optimizer.state.items():
            for key, value in state.items():
                value = np.ascontiguousarray(value.detach().cpu().numpy())
                arrays[f"optim.{names[id(parameter)]}.{key}"] = value
        meta = {
            "explore_rng": self.rng.bit_generator.state,
            "replay_rng": self.replay.rng.bit_generator.state,
            "num_gradient_steps": self.num_gradient_steps,
            "frozen_layers": list(self.frozen_layers),
        }
        return arrays, meta

    def load_training_state(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        self.replay.load_state_dict(
            {name[len("replay.") :]: value for name, value in arrays.items() if name.startswith("replay.")}
        )
        self.freeze(meta["frozen_layers"])
        # Through Adam's own load_state_dict (state keyed by parameter position), which puts each
        # moment on its parameter's device and keeps "step" where Adam expects it.
        optimizer_state = self.optimizer.state_dict()
        optimizer_state["state"] = {}
        for index, (name, _) in enumerate(self.q_network.named_parameters()):
            prefix = f"optim.{name}."
            state = {
                key[len(prefix) :]: torch.from_numpy(np.array(value))
                for key, value in arrays.items()
                if key.startswith(prefix)
            }
            if state:
                optimizer_state["state"][index] = state
        self.optimizer.load_state_dict(optimizer_state)
        self.rng.bit_generator.state = meta["explore_rng"]
        self.replay.rng.bit_generator.state = meta["replay_rng"]
        self.num_gradient_steps = int(meta["num_gradient_steps"])
