"""DQN and Double DQN for R replicas of a team of K agents, batched into one network module and one optimizer.

The algorithm is CleanRL's ``dqn.py`` per agent (read :meth:`BatchedDQN.update`, then the torch
engine's :meth:`~dqn_transfer.agents.dqn.DQNLearner.train_on`, the gradient step for all agents at
once): store the transition; every ``train_freq`` env steps after ``learning_starts``, take
``gradient_steps`` steps of Huber loss between ``Q(s, a)`` and the bootstrapped target on a uniform
replay batch (Adam, gradient-norm clip); every ``target_update`` env steps move the target network
``tau`` of the way to the online one (``tau == 1``: a hard copy) — the same rule as SB3's
``target_update_interval``/``tau`` and CleanRL's ``target_network_frequency``/``tau``.

What is particular here: all R x K agents are one batched network (stacked weights), their replay is
one ``[R * K, capacity, ...]`` storage, and one Adam step updates everyone. The loss is the *sum* of
the agents' mean losses, so each agent's gradient is exactly the one its own network would get, and
gradients are clipped per agent. With ``share_parameters`` each replica's team shares one network
instead (the parameter-sharing baseline): a single member whose forward pass serves its agents, replay
still per agent, loss the *mean* over the replica's agents. Replica r (rows ``r * K .. r * K + K - 1``)
has its own initial weights, exploration and replay sampling streams, seeded as a lone learner of its
seed would be; :meth:`BatchedDQN.replica` is its team (:mod:`dqn_transfer.agents.replicas`). With
``agent.mixer=vdn`` each replica's team is trained on one TD error instead, from a joint replay of its
aligned steps (``train_on`` with ``live``).

Two engines do the arithmetic (``agent.engine``): ``torch`` (:mod:`dqn_transfer.agents.dqn`, any
device and any loss: autograd and ``torch.optim.Adam``) and ``numpy`` (:mod:`dqn_transfer.agents.numpy_dqn`,
CPU only, no torch in the process, DQN / Double DQN / VDN: the fastest for a few small networks, and what
the default ``auto`` picks on the CPU). This module is what they share, and imports
neither torch nor an engine.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Iterable, Sequence
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from dqn_transfer.agents.agent_id import agent_id_rows, append_agent_id, with_agent_id
from dqn_transfer.agents.base import (
    Experience,
    ExperienceSharing,
    KnowledgeExchange,
    Learner,
    ObsLayout,
    Team,
    Transition,
    UpdateStats,
    WarmStart,
    check_tensor_shape,
    epsilon_greedy,
    joined,
)
from dqn_transfer.agents.replay import ReplayBatch, ReplayBuffer
from dqn_transfer.agents.replicas import team_view
from dqn_transfer.agents.shared_experience import SharedExperience
from dqn_transfer.config import AgentConfig
from dqn_transfer.enums import Algorithm, Mixer


class StackedNetwork(Protocol):
    """What :class:`BatchedDQN` uses of an engine's stacked MLPs (one member per agent, or per shared team)."""

    tensor_names: list[str]
    shapes: list[tuple[int, ...]]

    @property
    def num_layers(self) -> int: ...
    def member_state(self, m: int) -> dict[str, np.ndarray]: ...
    def load_member_state(self, m: int, state: dict[str, np.ndarray], name_prefix: str = "") -> None: ...
    def update_from(self, source: Any, tau: float, times: int = 1) -> None: ...


class StackedOptimizer(Protocol):
    """What :class:`BatchedDQN` uses of an engine's Adam (``torch.optim.Adam`` in
    :class:`~dqn_transfer.agents.dqn.StackedAdam`, :class:`~dqn_transfer.agents.numpy_dqn.NumpyAdam` in numpy):
    per stacked tensor i, whether it has state, its moments shaped as the tensor (write through them), its
    step count, and setting that count (creating zero moments if it had no state)."""

    @property
    def has_state(self) -> list[bool]: ...
    def moments(self, i: int, shape: Sequence[int]) -> dict[str, Any]: ...
    def step_count(self, i: int) -> int: ...
    def set_step(self, i: int, step: int) -> None: ...


NetworkT = TypeVar("NetworkT", bound=StackedNetwork)
OptimizerT = TypeVar("OptimizerT", bound=StackedOptimizer)


class BatchedDQN(Learner, KnowledgeExchange, ExperienceSharing, WarmStart, Generic[NetworkT, OptimizerT]):
    """K DQN / Double DQN agents, in R independent replicas (see the module docstring): a ``Learner``
    of the R x K agents as rows ``r * K + k`` (:meth:`replica` is one replica's team), with knowledge
    exchange, shared experience and warm start.

    ``obs_layout`` and ``obs_dim`` describe the networks' input: the game's observation, and with
    ``agent_id_input`` the ``agent_id`` segment the learner appends to it (:mod:`~dqn_transfer.agents.agent_id`).

    The engine contract: a subclass builds the members below in its ``__init__`` and implements the
    abstract methods (the engine hooks).
    """

    q_network: NetworkT  # the online networks
    optimizer: OptimizerT  # Adam over the online networks' tensors

    def __init__(
        self,
        num_agents: int,
        obs_layout: ObsLayout,
        num_actions: int,
        hp: AgentConfig | None = None,
        *,
        seed: int | Sequence[int] = 0,
    ) -> None:
        """
        :param num_agents: K, the agents of the team (each its own network unless ``share_parameters``)
        :param obs_layout: the observation's named segments ``[(name, size), ...]``
        :param num_actions: A, the discrete actions
        :param hp: the hyperparameters (None: the defaults), documented on
            :class:`~dqn_transfer.config.AgentConfig` (their one home, shared with the command line);
            ``hp.algorithm`` picks the DQN or Double DQN target
        :param seed: fixes the initial weights, exploration and replay sampling; a list of R seeds
            makes R replicas, replica r exactly the team a lone learner of ``seed[r]`` would be
        """
        hp = hp if hp is not None else AgentConfig()
        algorithm = Algorithm(hp.algorithm)
        if algorithm.is_tabular:
            raise ValueError(f"{type(self).__name__} trains the DQN family, not {algorithm.value}")
        self.agent_id_input = hp.agent_id_input
        network_layout = with_agent_id(obs_layout, num_agents) if self.agent_id_input else obs_layout
        super().__init__(algorithm, num_agents, network_layout, num_actions)
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
        self.vdn = Mixer(hp.mixer) is Mixer.vdn  # the team trained on one TD error (joint replay)
        self.seeds = [int(seed)] if isinstance(seed, (int, np.integer)) else [int(s) for s in seed]
        self.num_replicas = len(self.seeds)
        self.num_rows = self.num_replicas * num_agents
        self.members_per_replica = 1 if self.share_parameters else num_agents
        self.num_members = self.num_replicas * self.members_per_replica

        # Per replica, independent random streams: exploration and replay sampling (numpy, their states
        # are JSON-able); the engine draws the initial weights from the seed itself.
        streams = [np.random.SeedSequence(s).spawn(2) for s in self.seeds]
        self.rngs = [np.random.default_rng(explore) for explore, _ in streams]
        # Each row's agent-id columns (None: no such input); the replay stores the game's observations.
        self._agent_ids = agent_id_rows(self.num_rows, num_agents) if self.agent_id_input else None
        game_obs_dim = self.obs_dim - (num_agents if self.agent_id_input else 0)
        self.replay = ReplayBuffer(
            self.num_rows,
            hp.buffer_size,
            game_obs_dim,
            [np.random.default_rng(replay) for _, replay in streams],
            joint=self.vdn,
        )
        self.shared_experience: SharedExperience | None = None  # transfer.exchange=experience
        self.frozen_layers: list[int] = []
        self.num_gradient_steps = 0
        # What update returns when it does not train (read-only: the trainer only reads statistics).
        self._no_training = UpdateStats(np.full(self.num_rows, np.nan), np.full(self.num_rows, np.nan))
        self._loss_weights_cache: tuple[bytes, np.ndarray] | None = None
        self._target_syncs_due = 0  # target syncs of past env steps not yet applied (see learn)
        self._build_networks(num_actions)

    # ======================================================================== engine hooks
    @abstractmethod
    def _build_networks(self, num_actions: int) -> None:
        """Set :attr:`q_network` (its initial weights drawn from :attr:`seeds`, each replica's as a lone
        learner's), :attr:`target_network` (a copy) and :attr:`optimizer` (Adam, ``lr``), for
        :attr:`num_members` members of :attr:`obs_dim` inputs, :attr:`hidden` and ``num_actions`` outputs."""

    @abstractmethod
    def _online_q_values(self, inputs: np.ndarray, replica: int | None) -> np.ndarray:
        """The online networks' Q-values of their inputs: ``inputs`` float32 ``[rows, obs_dim] -> [rows, A]``
        (rows of ``replica``, or of all)."""

    @abstractmethod
    def _greedy_actions(self, inputs: np.ndarray, replica: int | None) -> np.ndarray:
        """``argmax_a Q(inputs, a)`` per row, ``inputs`` float32 ``[rows, obs_dim]`` (of ``replica``, or of all)."""

    @abstractmethod
    def train_on(
        self, batch: ReplayBatch, sample_weights: np.ndarray | None = None, live: np.ndarray | None = None
    ) -> UpdateStats:
        """One Adam step for all agents on ``batch`` (``[rows, B, ...]``, the networks' inputs); each row's
        loss is its batch's mean, or with ``sample_weights`` ``[rows, B]`` their weighted sum
        (:func:`~dqn_transfer.agents.dqn_update.td_losses`); with ``live`` ``[rows, B]`` (VDN: a replica's
        rows are the same joint steps) the loss is each replica's team's
        (:func:`~dqn_transfer.agents.dqn_update.team_td_errors`), every row reporting its team's loss."""

    @abstractmethod
    def _to_engine(self, array: np.ndarray) -> Any:
        """A numpy array as the engine's array type (on its device)."""

    @abstractmethod
    def _to_numpy(self, array: Any) -> np.ndarray:
        """An engine array as a numpy array on the host."""

    # ---------------------------------------------------------------------------- replicas
    def replica(self, r: int) -> Team:
        """Replica r's team of K agents (evaluation, transfer, exchange, checkpoints)."""
        return team_view(self, r)

    def _rows(self, replica: int) -> slice:
        k = self.num_agents
        return slice(replica * k, (replica + 1) * k)

    def _members(self, replica: int | None) -> slice | None:
        """Replica's members of the batched networks (None: all of them)."""
        m = self.members_per_replica
        return None if replica is None else slice(replica * m, (replica + 1) * m)

    def _network_inputs(self, obs: np.ndarray, replica: int | None = None) -> np.ndarray:
        """Observations ``[rows, ..., D]`` (rows of ``replica``, or of all) as the networks' inputs: with
        ``agent_id_input`` each row's agent-id one-hot appended, else the observations themselves."""
        if self._agent_ids is None:
            return obs
        return append_agent_id(obs, self._agent_ids if replica is None else self._agent_ids[self._rows(replica)])

    def _team_batch_numpy(self, obs: np.ndarray) -> np.ndarray:
        """``obs [rows, D]`` as the members' inputs ``[members, B, D]``: a shared network sees its
        replica's agents as one batch."""
        if self.share_parameters:
            return obs.reshape(-1, self.num_agents, obs.shape[-1])
        return obs[:, None, :]

    # ------------------------------------------------------------------------------ acting
    def q_values(self, obs: np.ndarray, replica: int | None = None) -> np.ndarray:
        """Each agent's online Q-values of its own observation: ``obs [rows, D] -> [rows, A]``."""
        return self._online_q_values(self._network_inputs(np.asarray(obs, dtype=np.float32), replica), replica)

    def act(
        self, obs: np.ndarray, live: np.ndarray, epsilon: float | np.ndarray, replica: int | None = None
    ) -> np.ndarray:
        """Per-agent epsilon-greedy (rows of ``replica``, or all); one forward pass for every agent,
        skipped if everyone explores. Every row draws its exploration numbers, live or not (the stream
        does not depend on who is live); non-live agents' actions are then 0."""
        obs = np.asarray(obs, dtype=np.float32)
        # The exploration draws come first, from the shared epsilon_greedy (the same draws, so the same
        # random stream): given -1 as every greedy action, it returns -1 exactly where the agent exploits.
        epsilon = np.asarray(epsilon, dtype=np.float64)
        if epsilon.ndim == 0:
            epsilon = np.full(obs.shape[0], epsilon)
        k = self.num_agents
        replicas = range(self.num_replicas) if replica is None else [replica]
        undecided = np.full(k, -1, dtype=np.int64)
        draws = [
            epsilon_greedy(undecided, epsilon[i * k : (i + 1) * k], self.num_actions, self.rngs[r])
            for i, r in enumerate(replicas)
        ]
        actions = joined(draws)
        exploit = actions < 0
        if exploit.any():
            np.copyto(actions, self._greedy_actions(self._network_inputs(obs, replica), replica), where=exploit)
        np.copyto(actions, 0, where=~np.asarray(live, dtype=bool))
        return actions

    def greedy_actions(self, obs: np.ndarray) -> np.ndarray:
        """``argmax_a Q(obs, a)`` of every row, ``obs`` float32 ``[rows, D]`` (the game's observations)."""
        return self._greedy_actions(self._network_inputs(obs), None)

    def best_actions(self, obs: np.ndarray, replica: int | None = None) -> np.ndarray:
        """The first best action of each row (network outputs practically never tie), as a mask."""
        greedy = self._greedy_actions(self._network_inputs(np.asarray(obs, dtype=np.float32), replica), replica)
        best = np.zeros((len(greedy), self.num_actions), dtype=bool)
        best[np.arange(len(greedy)), greedy] = True
        return best

    # ---------------------------------------------------------------------------- learning
    def update(self, transition: Transition, step: int) -> UpdateStats:
        """Store the live agents' transitions, then :meth:`learn`."""
        self.replay.add(transition)
        return self.learn(step)

    def learn(self, step: int) -> UpdateStats:
        """Train on schedule, sync the target on schedule (what :meth:`update` does once the step is stored).

        ``step`` counts env steps including this one (the same for every replica: they run in
        lockstep). The statistics are averaged over this round's gradient steps (``q_mean``: mean
        ``Q(s, a)`` of the batch), nan if no training.
        """
        stats = self._no_training
        if step > self.learning_starts and step % self.train_freq == 0:
            rounds = [self.gradient_step() for _ in range(self.gradient_steps)]
            if len(rounds) == 1:  # the mean of one round, without np.mean's cost
                columns = [column.astype(np.float64) for column in rounds[0]]
            else:
                columns = [np.asarray(np.mean(column, axis=0, dtype=np.float64)) for column in zip(*rounds)]
            stats = UpdateStats(*columns)

        if step % self.target_update == 0:
            # Applied when the target is next read or before the online networks next change: every sync
            # in between moves toward the same online weights, so a Polyak target's syncs of several env
            # steps take one pass over the parameters (each rounded as if applied at its own step).
            self._target_syncs_due += 1
        return stats

    @property
    def target_network(self) -> NetworkT:
        """The target networks, with every target sync due so far applied."""
        self._apply_target_syncs()
        return self._target_network

    @target_network.setter
    def target_network(self, network: NetworkT) -> None:
        self._target_network, self._target_syncs_due = network, 0

    def _apply_target_syncs(self) -> None:
        """Move the target networks by the syncs due (:meth:`learn`); called before the online ones change."""
        if self._target_syncs_due:
            self._target_network.update_from(self.q_network, self.tau, self._target_syncs_due)
            self._target_syncs_due = 0

    @property
    def trainable_layers(self) -> list[int]:
        return [l for l in range(self.q_network.num_layers) if l not in self.frozen_layers]

    def gradient_step(self) -> UpdateStats:
        """One Adam step for all agents on a fresh replay batch (what ``update`` runs on schedule): each
        agent's own, or with shared experience drawn from all its team-mates' replays."""
        live = None
        if self.vdn:
            (batch, live), sample_weights = self.replay.sample_joint(self.batch_size), None
        elif self.shared_experience is None:
            batch, sample_weights = self.replay.sample(self.batch_size), None
        else:
            batch = self.replay.sample_rows(self.shared_experience.sources)
            sample_weights = self.shared_experience.sample_weights(self.replay.size > 0)
        if self._agent_ids is not None:
            batch = batch._replace(obs=self._network_inputs(batch.obs), next_obs=self._network_inputs(batch.next_obs))
        return self.train_on(batch, sample_weights, live)

    def share_experience(self, experience_lambda: float) -> None:
        """Draw every agent's batches from all its team-mates' replays (its replica's), their samples weighing
        ``experience_lambda`` times its own (:mod:`~dqn_transfer.agents.shared_experience`)."""
        self.shared_experience = SharedExperience(
            self.num_replicas, self.num_agents, self.batch_size, experience_lambda
        )

    def loss_weights(self, valid: np.ndarray) -> np.ndarray:
        """``[rows]`` weight of each row's mean loss in the total: 1 (each agent's gradient is its own
        loss's), with a shared network 1 / (its replica's agents with data), the usual batch mean;
        0 for a row with no data yet (its batch is placeholders). With VDN the weight of each replica's
        one team loss, on all its rows: 1, shared network or not. Cached while the same rows have data
        (the same array is returned, so an engine may key its own copy on it)."""
        key = valid.tobytes()
        if self._loss_weights_cache is None or self._loss_weights_cache[0] != key:
            weights = valid.astype(np.float32)
            if self.share_parameters and not self.vdn:
                counts = np.maximum(valid.reshape(-1, self.num_agents).sum(axis=1), 1).astype(np.float32)
                weights = weights / np.repeat(counts, self.num_agents)
            self._loss_weights_cache = (key, weights)
        return self._loss_weights_cache[1]

    # ------------------------------------------------------------------ transfer and exchange
    def soft_copy_best(self, best: int, tau: float, replica: int = 0) -> None:
        """Every other agent of ``replica``'s team moves its online weights ``tau`` of the way to agent
        ``best``'s (frozen layers stay as they are; the targets follow at their next sync)."""
        rows = self._rows(replica)
        best_weights = self.get_member_weights(rows.start + best)
        frozen = {f"layers.{l}.{kind}" for l in self.frozen_layers for kind in ("weight", "bias")}
        for i in range(rows.start, rows.stop):
            if i != rows.start + best:
                own = self.get_member_weights(i)
                self.set_member_weights(
                    i,
                    {
                        name: own[name] if name in frozen else (1 - tau) * own[name] + tau * best_weights[name]
                        for name in own
                    },
                )

    def learn_from(self, i: int, experience: Experience) -> None:
        """Append a team-mate's ``[N, ...]`` transitions to agent i's replay row."""
        self.replay.extend(i, *experience)

    def freeze(self, layer_indices: Iterable[int]) -> None:
        """Keep these layers' weights and biases fixed (negative indices count from the output).

        The weights of a layer are one stacked tensor for all agents, so freezing applies to the
        whole team (and every replica). A frozen layer gets no gradient and Adam skips it, so not
        even leftover momentum moves it.
        """
        layers = [range(self.q_network.num_layers)[index] for index in layer_indices]  # IndexError if absent
        self.frozen_layers = sorted({*self.frozen_layers, *layers})

    def load_optimizer_state(self, i: int, moments: dict[str, dict[str, np.ndarray]], step: int) -> None:
        """Adam moments for agent i's slice of each stacked tensor, e.g. carried over by transfer.

        ``moments[name]`` holds ``exp_avg`` and ``exp_avg_sq`` shaped like one member's slice of
        tensor ``name``. Adam keeps one ``step`` per stacked tensor, shared by all agents.
        """
        m = self._member(i)
        optimizer, network = self.optimizer, self.q_network
        for index, name in enumerate(network.tensor_names):
            if name not in moments:  # e.g. a layer the source kept frozen has no moments
                continue
            optimizer.set_step(index, int(step))
            for key, moment in optimizer.moments(index, network.shapes[index]).items():
                moment[m] = self._to_engine(np.asarray(moments[name][key]))

    def _member(self, i: int) -> int:
        if not 0 <= i < self.num_rows:
            raise IndexError(f"agent index {i} out of range for {self.num_rows} agents")
        return i // self.num_agents if self.share_parameters else i

    def get_member_weights(self, i: int) -> dict[str, np.ndarray]:
        """Agent i's online network, ``layers.{l}.weight`` ``[out, in]`` / ``layers.{l}.bias``."""
        return self.q_network.member_state(self._member(i))

    def set_member_weights(self, i: int, tensors: dict[str, np.ndarray]) -> None:
        """Overwrite agent i's online network (the target follows at its next sync)."""
        self._apply_target_syncs()
        self.q_network.load_member_state(self._member(i), tensors)

    # -------------------------------------------------------------------------- checkpoints
    def agent_tensors(self, i: int) -> dict[str, np.ndarray]:
        """``q.layers.{l}.weight|bias`` (online) and ``target.layers.{l}.weight|bias``.

        With ``share_parameters`` every agent returns the one shared network.
        """
        m = self._member(i)
        tensors = {f"q.{name}": t for name, t in self.q_network.member_state(m).items()}
        tensors.update({f"target.{name}": t for name, t in self.target_network.member_state(m).items()})
        return tensors

    def load_agent_tensors(self, i: int, tensors: dict[str, np.ndarray]) -> None:
        """Load ``q.*`` and, if present, ``target.*`` (else the target becomes a copy of ``q.*``).

        With ``share_parameters`` all agents load into the one shared network: the last load wins.
        """
        m = self._member(i)
        online = {name[2:]: t for name, t in tensors.items() if name.startswith("q.")}
        target = {name[7:]: t for name, t in tensors.items() if name.startswith("target.")}
        self._apply_target_syncs()
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

    def training_state(self, replica: int = 0) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """One replica's Adam moments (by tensor name), replay storage and pointers, RNG states, counters.

        The network weights themselves are in ``agent_tensors``: resume = ``load_agent_tensors``
        for every agent, then ``load_training_state``.
        """
        if not 0 <= replica < self.num_replicas:
            raise IndexError(f"replica {replica} out of range for {self.num_replicas} replicas")
        arrays = {f"replay.{name}": value for name, value in self.replay.state_dict(self._rows(replica)).items()}
        optimizer, network, members = self.optimizer, self.q_network, self._members(replica)
        for index, name in enumerate(network.tensor_names):
            if optimizer.has_state[index]:
                for key, moment in optimizer.moments(index, network.shapes[index]).items():
                    arrays[f"optim.{name}.{key}"] = np.ascontiguousarray(self._to_numpy(moment[members]))
                arrays[f"optim.{name}.step"] = np.array(optimizer.step_count(index), dtype=np.float32)
        meta = {
            "explore_rng": self.rngs[replica].bit_generator.state,
            "replay_rng": self.replay.rngs[replica].bit_generator.state,
            "num_gradient_steps": self.num_gradient_steps,
            "frozen_layers": list(self.frozen_layers),
        }
        return arrays, meta

    def load_training_state(self, arrays: dict[str, np.ndarray], meta: dict[str, Any], replica: int = 0) -> None:
        self.replay.load_state_dict(
            {name[len("replay.") :]: value for name, value in arrays.items() if name.startswith("replay.")},
            self._rows(replica),
        )
        self.freeze(meta["frozen_layers"])
        optimizer, network, members = self.optimizer, self.q_network, self._members(replica)
        for index, name in enumerate(network.tensor_names):
            prefix = f"optim.{name}."
            if prefix + "step" not in arrays:
                continue
            shape = network.shapes[index]
            optimizer.set_step(index, int(np.asarray(arrays[prefix + "step"]).reshape(-1)[0]))
            for key, moment in optimizer.moments(index, shape).items():
                value = np.array(arrays[prefix + key], dtype=np.float32)
                check_tensor_shape(prefix + key, value, (self.members_per_replica, *shape[1:]))
                moment[members] = self._to_engine(value)
        self.rngs[replica].bit_generator.state = meta["explore_rng"]
        self.replay.rngs[replica].bit_generator.state = meta["replay_rng"]
        self.num_gradient_steps = int(meta["num_gradient_steps"])
