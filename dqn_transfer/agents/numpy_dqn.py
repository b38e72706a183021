"""The ``numpy`` engine of :class:`~dqn_transfer.agents.dqn_base.BatchedDQN`: CPU only, no torch in the process.

A fast path for the losses it implements (DQN, Double DQN, VDN); the torch engine
(:meth:`~dqn_transfer.agents.dqn.DQNLearner.train_on`) states the update, runs anything else, and is what
this engine is checked against, step for step. For networks this small (a few 64x64 MLPs) a gradient
step is a few dozen tiny array operations, and what they cost is per-call overhead, not arithmetic:
numpy's is a fraction of torch's (autograd and ``torch.optim`` included), and a process that never
imports torch starts seconds sooner. The target, the Huber loss and the clip rule are
:mod:`dqn_transfer.agents.dqn_update`'s, shared with the torch engine; this module holds the loss's
gradient and the numeric kernels (forward, the chain rule through ReLU layers, per-member gradient norms,
Adam's arithmetic), in float32 with numpy's kernels: results agree with the torch engine to float32
rounding, not bit for bit, and the initial weights come from numpy's generator (same distribution as
``nn.Linear``'s, other numbers). ``agent.engine`` is therefore part of what a run is (its config and
checkpoints record it).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dqn_transfer.agents.base import UpdateStats
from dqn_transfer.agents.dqn_base import BatchedDQN
from dqn_transfer.agents.dqn_update import (
    clip_coefficient,
    double_dqn_targets,
    dqn_targets,
    huber,
    live_mean,
    td_losses,
    team_td_errors,
)
from dqn_transfer.agents.replay import ReplayBatch
from dqn_transfer.agents.stacked import FLUSH_EVERY, SMALLEST_NORMAL, StackedLayout
from dqn_transfer.compiled import array_kernel

WEIGHT_STREAM = 2  # SeedSequence spawn key of the initial weights (0 and 1: exploration and replay)


def huber_grad(error: np.ndarray) -> np.ndarray:
    """d :func:`~dqn_transfer.agents.dqn_update.huber` / d error: the TD error clipped to ``[-1, 1]``."""
    return np.clip(error, -1.0, 1.0)


def td_loss_grad(error: np.ndarray, weights: np.ndarray, sample_weights: np.ndarray | None = None) -> np.ndarray:
    """d loss / d ``Q(s, a)`` ``[rows, B]`` for the loss ``sum_rows weights[row] * td_losses(error,
    sample_weights)[row]`` (``weights`` ``[rows]``: see ``BatchedDQN.loss_weights``)."""
    if sample_weights is None:
        return huber_grad(error) * (weights[:, None] / error.shape[-1])
    return huber_grad(error) * (weights[:, None] * sample_weights)


def team_losses(team_error: np.ndarray, num_agents: int) -> np.ndarray:
    """Each agent's row ``[rows]``: its team's loss, the mean ``huber`` of its ``team_td_errors``."""
    return np.repeat(huber(team_error).mean(-1), num_agents)


def team_loss_grad(team_error: np.ndarray, live: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """d loss / d ``Q_k(s, a)`` ``[rows, B]`` for VDN's loss ``sum_teams weights[team] * mean_b
    huber(team_error)``: every agent live in a sample gets its team's gradient there (d Q_tot / d Q_k = 1),
    the others none. ``weights`` ``[rows]`` is the same for a team's rows (see ``BatchedDQN.loss_weights``)."""
    teams, batch = team_error.shape
    k = live.shape[0] // teams
    grad = huber_grad(team_error)[:, None, :] * live.reshape(teams, k, batch) * (weights.reshape(teams, k, 1) / batch)
    return grad.reshape(teams * k, batch)


class NumpyMLP(StackedLayout):
    """``num_members`` ReLU MLPs ``in_dim -> hidden... -> out_dim``, stacked: ``weight_l [M, in, out]``,
    ``bias_l [M, out]``, all views of one flat float32 buffer ``flat`` (gradients: ``flat_grad``).

    :param num_members: M, the stacked networks
    :param in_dim: inputs
    :param hidden: hidden layer sizes
    :param out_dim: outputs
    :param rngs: one generator per equal block of members (a replica), drawing its block's initial
        weights layer by layer (``nn.Linear``'s distribution); None: all zeros (a target network)
    """

    def __init__(
        self,
        num_members: int,
        in_dim: int,
        hidden: Sequence[int],
        out_dim: int,
        rngs: Sequence[np.random.Generator] | None = None,
    ) -> None:
        super().__init__(num_members, in_dim, hidden, out_dim)
        self.flat = np.zeros(self.num_parameters, dtype=np.float32)
        self.flat_grad = np.zeros(self.num_parameters, dtype=np.float32)
        self.tensors = self.views(self.flat)
        self.grads = self.views(self.flat_grad)
        # Per layer: the weight and the bias as a [M, 1, out] row to broadcast over the batch.
        self._affine = [(self.tensors[2 * l], self.tensors[2 * l + 1][:, None, :]) for l in range(self.num_layers)]
        if rngs is not None:
            self._initialise(rngs)

    def _initialise(self, rngs: Sequence[np.random.Generator]) -> None:
        for r, members, l, _fan_in, bound in self.initial_draws(len(rngs)):
            weight, bias = self.layer(l)
            weight[members] = rngs[r].uniform(-bound, bound, size=weight[members].shape)
            bias[members] = rngs[r].uniform(-bound, bound, size=bias[members].shape)

    def layer(self, l: int) -> tuple[np.ndarray, np.ndarray]:
        """Layer l's ``(weight [M, in, out], bias [M, out])``, views of ``flat``."""
        return self.tensors[2 * l], self.tensors[2 * l + 1]

    # ------------------------------------------------------------------------- forward
    def predict(
        self, x: np.ndarray, members: slice | None = None, inputs: list[np.ndarray] | None = None
    ) -> np.ndarray:
        """``x [len(members), B, in] -> [len(members), B, out]`` for ``members`` (default all); every
        layer's input is appended to ``inputs`` if given (what :meth:`backward` needs)."""
        last = self.num_layers - 1
        for l, (weight, bias) in enumerate(self._affine):
            if members is not None:
                weight, bias = weight[members], bias[members]
            if inputs is not None:
                inputs.append(x)
            x = np.matmul(x, weight)
            x += bias
            if l < last:
                np.maximum(x, 0.0, out=x)
        return x

    def backward(self, inputs: list[np.ndarray], grad_out: np.ndarray, layers: Sequence[int]) -> None:
        """Gradients of the trainable ``layers`` into :attr:`grads` (the others are left as they are),
        given d loss / d output ``grad_out [M, B, out]`` and the inputs :meth:`predict` collected."""
        wanted = set(layers)
        if not wanted:
            return
        grad = grad_out
        for l in range(self.num_layers - 1, min(wanted) - 1, -1):
            if l in wanted:
                np.matmul(inputs[l].transpose(0, 2, 1), grad, out=self.grads[2 * l])
                np.sum(grad, axis=1, out=self.grads[2 * l + 1])
            if l > min(wanted):
                grad = np.matmul(grad, self.layer(l)[0].transpose(0, 2, 1))
                grad *= inputs[l] > 0  # ReLU: the gradient passes where its output was positive

    def clip_grad_norm_(self, max_norm: float, layers: Sequence[int]) -> None:
        """Scale each member's gradients of ``layers`` to a norm of at most ``max_norm`` (the torch
        engine's per-member ``clip_grad_norm_``: one agent's large gradient never shrinks another's)."""
        tensors = [2 * l + kind for l in layers for kind in (0, 1)]
        if not tensors:
            return
        flat = self.flat_grad
        if float(np.dot(flat, flat)) < (0.99 * max_norm) ** 2:
            return  # no member's norm exceeds the norm of all gradients together: nobody is clipped
        squares = sum(
            np.einsum("mi,mi->m", g, g) for g in (self.grads[i].reshape(self.num_members, -1) for i in tensors)
        )
        scale = clip_coefficient(np.sqrt(squares), max_norm)
        if (scale < 1.0).any():
            for i in tensors:
                self.grads[i] *= scale.reshape(-1, *([1] * (len(self.shapes[i]) - 1)))

    # ------------------------------------------------------------------------- members
    def member_state(self, m: int) -> dict[str, np.ndarray]:
        """Member m's weights as copies in ``nn.Linear`` layout (``layers.{l}.weight`` ``[out, in]``)."""
        state = {}
        for l in range(self.num_layers):
            weight, bias = self.layer(l)
            state[f"layers.{l}.weight"] = np.ascontiguousarray(weight[m].T)
            state[f"layers.{l}.bias"] = bias[m].copy()
        return state

    def load_member_state(self, m: int, state: dict[str, np.ndarray], name_prefix: str = "") -> None:
        """Overwrite member m from ``nn.Linear``-layout arrays (all layers must be present); everything
        is checked before anything is written (:meth:`check_member_state`)."""
        self.check_member_state(state, name_prefix)
        for l in range(self.num_layers):
            weight, bias = self.layer(l)
            weight[m] = np.asarray(state[f"layers.{l}.weight"]).T
            bias[m] = state[f"layers.{l}.bias"]

    def update_from(self, source: NumpyMLP, tau: float, times: int = 1) -> None:
        """Move towards ``source``, ``times`` target syncs in a row: exact copy when ``tau == 1`` (hard target
        update), else Polyak ``p <- p + tau * (p_source - p)`` ``times`` times."""
        if tau == 1.0:
            np.copyto(self.flat, source.flat)
        else:
            polyak_steps(self.flat, source.flat, np.float32(tau), times)


BLOCK = 1024  # parameters a pass of a kernel below takes at a time: in the L1 cache for all of its work


@array_kernel
def polyak_steps(target: np.ndarray, source: np.ndarray, tau: np.float32, times: int) -> None:
    """``times`` steps ``target += tau * (source - target)`` in float32, each rounded at each operation as
    numpy's subtract, scale and add are, in one pass over the parameters (a block at a time) instead of three
    passes a step: a Polyak target moves every env step and is read every ``train_freq``."""
    for start in range(0, target.size, BLOCK):
        # Views of the block, indexed from 0: what lets LLVM vectorise the loop (``start + i`` does not).
        block, towards = target[start : start + BLOCK], source[start : start + BLOCK]
        for _ in range(times):
            for i in range(block.size):
                block[i] += (towards[i] - block[i]) * tau


class NumpyAdam:
    """Adam (``torch.optim.Adam``'s defaults and arithmetic order) over the tensors ``spans`` of one flat
    buffer, one pass per stretch of neighbouring tensors at the same step count, with
    ``torch.optim.Adam``'s rules: state exists for a tensor from its first step on (or from
    :meth:`init_state`), and a tensor that gets no gradient in a step (a frozen layer) is skipped
    entirely, its moments and step count kept.

    :param flat: the parameters, one 1-D float32 array
    :param flat_grad: their gradients, same shape
    :param spans: the ``[start, end)`` range of each tensor, in order and without overlap
    :param lr: the step size
    :param betas: the moments' decay rates
    :param eps: added to the denominator
    """

    def __init__(
        self,
        flat: np.ndarray,
        flat_grad: np.ndarray,
        spans: Sequence[tuple[int, int]],
        lr: float,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        self.spans = list(spans)
        self.exp_avg, self.exp_avg_sq = np.zeros_like(flat), np.zeros_like(flat)
        self.steps = [0] * len(self.spans)
        self.has_state = [False] * len(self.spans)
        self.flat, self.flat_grad = flat, flat_grad
        self.lr, (self.beta1, self.beta2), self.eps = lr, betas, eps

    def moments(self, i: int, shape: Sequence[int]) -> dict[str, np.ndarray]:
        """Tensor i's ``exp_avg`` and ``exp_avg_sq``, as views of shape ``shape`` (write through them)."""
        a, b = self.spans[i]
        return {
            "exp_avg": self.exp_avg[a:b].reshape(tuple(shape)),
            "exp_avg_sq": self.exp_avg_sq[a:b].reshape(tuple(shape)),
        }

    def step_count(self, i: int) -> int:
        """Tensor i's Adam steps so far."""
        return self.steps[i]

    def set_step(self, i: int, step: int) -> None:
        """Set tensor i's step count, giving it zero moments first if it has no state (e.g. loading a checkpoint)."""
        self.init_state(i)
        self.steps[i] = step

    def init_state(self, i: int) -> None:
        """Give tensor i the state Adam creates at its first step (zero moments, step 0), if it has none."""
        if not self.has_state[i]:
            a, b = self.spans[i]
            self.exp_avg[a:b] = 0.0
            self.exp_avg_sq[a:b] = 0.0
            self.steps[i] = 0
            self.has_state[i] = True

    def count_step(self, active: Sequence[int]) -> bool:
        """Count one step of the tensors ``active``; returns whether the subnormal moments are due
        for a flush (every ``FLUSH_EVERY`` steps of a saved count, so a resumed run flushes alike)."""
        for i in active:
            self.init_state(i)
            self.steps[i] += 1
        return bool(active) and self.steps[active[0]] % FLUSH_EVERY == 0

    def stretches(self, active: Sequence[int]) -> list[tuple[int, int, int]]:
        """Neighbouring ``active`` tensors at the same step count, merged: ``(start, end, a tensor of it)``
        (one update pass each instead of one per tensor)."""
        merged: list[list[int]] = []  # [start, end, step, first index]
        for i in sorted(active):
            (a, b), step = self.spans[i], self.steps[i]
            if merged and merged[-1][1] == a and merged[-1][2] == step:
                merged[-1][1] = b
            else:
                merged.append([a, b, step, i])
        return [(a, b, i) for a, b, _, i in merged]

    def step(self, active: Sequence[int]) -> None:
        """One Adam step for the tensors ``active`` (the others got no gradient)."""
        flush = self.count_step(active)
        for a, b, i in self.stretches(active):
            self._update(slice(a, b), self.steps[i])
        if flush:  # subnormal moments, too small to move any weight, slow every kernel reading them
            for moment in (self.exp_avg, self.exp_avg_sq):
                moment[np.abs(moment) < SMALLEST_NORMAL] = 0.0

    def _update(self, span: slice, step: int) -> None:
        bias_correction1 = 1 - self.beta1**step
        bias_correction2_sqrt = (1 - self.beta2**step) ** 0.5
        adam_step(
            self.flat[span],
            self.flat_grad[span],
            self.exp_avg[span],
            self.exp_avg_sq[span],
            np.float32(1 - self.beta1),
            np.float32(self.beta2),
            np.float32(1 - self.beta2),
            np.float32(bias_correction2_sqrt),
            np.float32(self.eps),
            np.float32(-self.lr / bias_correction1),
        )


@array_kernel
def adam_step(
    param: np.ndarray,
    grad: np.ndarray,
    exp_avg: np.ndarray,
    exp_avg_sq: np.ndarray,
    one_minus_beta1: np.float32,
    beta2: np.float32,
    one_minus_beta2: np.float32,
    bias_correction2_sqrt: np.float32,
    eps: np.float32,
    step_size: np.float32,
) -> None:
    """One Adam step of ``param`` in float32 (``step_size``: ``-lr / bias_correction1``), in ``torch.optim.Adam``'s
    order of operations, each rounded as numpy's would be: one pass over the parameters (a block at a time)
    instead of numpy's thirteen."""
    for start in range(0, param.size, BLOCK):
        p, g = param[start : start + BLOCK], grad[start : start + BLOCK]
        m, v = exp_avg[start : start + BLOCK], exp_avg_sq[start : start + BLOCK]
        for i in range(p.size):
            m[i] += (g[i] - m[i]) * one_minus_beta1  # exp_avg.lerp_(grad, 1 - beta1)
            v[i] = v[i] * beta2 + (g[i] * g[i]) * one_minus_beta2
            p[i] += m[i] / (np.sqrt(v[i]) / bias_correction2_sqrt + eps) * step_size


class NumpyDQNLearner(BatchedDQN):
    """:class:`~dqn_transfer.agents.dqn_base.BatchedDQN` in numpy, on the CPU."""

    def _build_networks(self, num_actions: int) -> None:
        weight_rngs = [np.random.default_rng(np.random.SeedSequence(s, spawn_key=(WEIGHT_STREAM,))) for s in self.seeds]
        self.q_network = NumpyMLP(self.num_members, self.obs_dim, self.hidden, num_actions, weight_rngs)
        self.target_network = NumpyMLP(self.num_members, self.obs_dim, self.hidden, num_actions)
        self.target_network.update_from(self.q_network, tau=1.0)
        self.optimizer = NumpyAdam(self.q_network.flat, self.q_network.flat_grad, self.q_network.spans, lr=self.lr)
        self._grid: tuple[np.ndarray, np.ndarray] | None = None

    def _to_engine(self, array: np.ndarray) -> np.ndarray:
        return array

    def _to_numpy(self, array: np.ndarray) -> np.ndarray:
        return array

    def _predict(
        self, network: NumpyMLP, obs: np.ndarray, replica: int | None = None, inputs: list[np.ndarray] | None = None
    ) -> np.ndarray:
        """``obs [rows, B, D] -> Q [rows, B, A]`` (rows of one replica, or of all)."""
        rows, batch, width = obs.shape
        if self.share_parameters:  # a shared network sees its replica's agents as one batch
            obs = obs.reshape(rows // self.num_agents, self.num_agents * batch, width)
        return network.predict(obs, self._members(replica), inputs).reshape(rows, batch, -1)

    def _online_q_values(self, inputs: np.ndarray, replica: int | None) -> np.ndarray:
        return self._predict(self.q_network, inputs[:, None, :], replica)[:, 0]

    def _greedy_actions(self, inputs: np.ndarray, replica: int | None) -> np.ndarray:
        return self._online_q_values(inputs, replica).argmax(axis=-1)

    def train_on(
        self, batch: ReplayBatch, sample_weights: np.ndarray | None = None, live: np.ndarray | None = None
    ) -> UpdateStats:
        """One Adam step for all agents on ``batch`` (``[rows, B, ...]``): the torch engine's loss,
        ``sum_rows weight[row] * td_losses(Q(s, a) - y, sample_weights)[row]`` (with ``live``, VDN's team
        loss), and its gradient by the chain rule."""
        obs, actions, rewards, next_obs, terminated = batch
        rows, cols = self._batch_grid(actions.shape)  # (row, sample) of each Q(s, a) picked below
        next_q_target = self._predict(self.target_network, next_obs)
        if self.double:
            targets = double_dqn_targets(
                rewards, self._predict(self.q_network, next_obs), next_q_target, terminated, self.gamma
            )
        else:
            targets = dqn_targets(rewards, next_q_target, terminated, self.gamma)

        inputs: list[np.ndarray] = []
        q_values = self._predict(self.q_network, obs, inputs=inputs)
        q_taken = q_values[rows, cols, actions]  # Q(s, a) [rows, B]
        error = q_taken - targets
        valid = self.replay.size > 0

        # d loss / d Q(s, a), scattered onto the actions taken, then back through the network.
        if live is None:
            agent_losses = td_losses(error, sample_weights)
            grad_taken = td_loss_grad(error, self.loss_weights(valid), sample_weights)
            q_mean = q_taken.mean(axis=1)
        else:
            team_error = team_td_errors(error, live, self.num_agents)
            agent_losses = team_losses(team_error, self.num_agents)
            grad_taken = team_loss_grad(team_error, live, self.loss_weights(valid))
            q_mean = live_mean(q_taken, live)
        grad_q = np.zeros_like(q_values)
        grad_q[rows, cols, actions] = grad_taken
        if self.share_parameters:
            grad_q = grad_q.reshape(len(inputs[0]), -1, grad_q.shape[-1])
        layers = self.trainable_layers
        self.q_network.backward(inputs, grad_q, layers)
        self.q_network.clip_grad_norm_(self.max_grad_norm, layers)
        self.optimizer.step([2 * l + kind for l in layers for kind in (0, 1)])
        self.num_gradient_steps += 1
        return UpdateStats(np.where(valid, agent_losses, np.nan), np.where(valid, q_mean, np.nan))

    def _batch_grid(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Index grids ``[rows, 1]`` and ``[1, B]`` that, with ``[rows, B]`` actions, pick one Q-value per sample."""
        if self._grid is None or self._grid[0].shape[0] != shape[0] or self._grid[1].shape[1] != shape[1]:
            self._grid = (np.arange(shape[0])[:, None], np.arange(shape[1])[None, :])
        return self._grid
