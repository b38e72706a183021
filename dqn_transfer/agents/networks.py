"""M independent MLPs evaluated as one: stacked weights, batched matrix products, one flat parameter.

A team of K DQN agents (and R replicas of a team) would otherwise run M small forward passes and M
optimizer steps per env step, which is dominated by Python and kernel-launch overhead. Stacking
member m's layer-l weight as ``weight_l[m]`` (``[in, out]``) lets one ``torch.baddbmm`` per layer
evaluate all members, while each member stays mathematically its own network: member m's outputs
depend only on ``weight_l[m]``, ``bias_l[m]``, so its gradients are exactly what a separate
``nn.Sequential(nn.Linear, nn.ReLU, ...)`` would get from the same loss.

All tensors live in one flat ``[P]`` Parameter (layer by layer: ``weight_0``, ``bias_0``,
``weight_1``, ...), so a target sync is one copy and Adam is a few kernels over one buffer.

Training does not go through autograd: :meth:`BatchedMLP.forward_cached` keeps the activations and
:meth:`BatchedMLP.backward` applies the chain rule with the same public kernels, in the same order,
as autograd's derivative formulas for ``baddbmm`` and ``relu`` (so the gradients are bit-identical to
``loss.backward()``, which the tests check), without the autograd engine's bookkeeping, which on
networks this small costs as much as the arithmetic (``scripts/time_dqn_backward.py``). ``forward``
itself stays differentiable.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from dqn_transfer.agents.dqn_update import clip_coefficient
from dqn_transfer.agents.stacked import StackedLayout


class BatchedMLP(nn.Module, StackedLayout):
    """``num_members`` ReLU MLPs ``in_dim -> hidden... -> out_dim`` with stacked parameters.

    Tensors ``weight_{l}`` ``[M, in, out]`` and ``bias_{l}`` ``[M, out]`` for each layer l are views of
    the one Parameter ``flat`` (``tensors``, :meth:`layer`, :meth:`named_tensors`; no autograd history);
    ``grads`` are the same views of ``flat_grad``, where :meth:`backward` writes. ``member_state``
    converts member m to the ``nn.Linear`` convention (``layers.{l}.weight`` ``[out, in]``) used in checkpoints.

    ``generators``: one per equal block of members (a replica), each drawing its block's initial
    weights layer by layer, so a block starts exactly as a network of that block alone seeded the
    same way would. None: all zeros (a target network, which copies its online network).
    """

    def __init__(
        self,
        num_members: int,
        in_dim: int,
        hidden: Sequence[int],
        out_dim: int,
        generators: Sequence[torch.Generator] | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        nn.Module.__init__(self)
        StackedLayout.__init__(self, num_members, in_dim, hidden, out_dim)
        offset = self.num_parameters
        self.flat = nn.Parameter(torch.zeros(offset, device=device))
        self.flat_grad = torch.zeros(offset, device=device)
        data = self.flat.detach()
        self.tensors = self.views(data)
        self.grads = self.views(self.flat_grad)
        # For the per-member clip: squared gradients, each tensor's as [M, numel / M], and which member
        # every element of the flat buffer belongs to.
        self._squares = torch.zeros(offset, device=device)
        self._squares_by_member = [self._squares[a:b].view(num_members, -1) for a, b in self.spans]
        self._member_of = torch.cat(
            [torch.arange(num_members, device=device).repeat_interleave(math.prod(shape[1:])) for shape in self.shapes]
        )
        # Per layer: the weight and the bias as a [M, 1, out] row to broadcast over the batch.
        self._affine = [(self.tensors[2 * l], self.tensors[2 * l + 1].unsqueeze(1)) for l in range(self.num_layers)]
        # The same as numpy arrays sharing the memory (CPU), for predict_numpy.
        self._affine_arrays = [(w.numpy(), b.numpy()) for w, b in self._affine] if data.device.type == "cpu" else None
        if generators:
            self._initialise(generators)

    def _apply(self, fn, recurse=True):
        # .to(), .cuda(), .double() ... would give ``flat`` new storage behind the views' back.
        raise TypeError("a BatchedMLP is built on its device (device=...) and cannot be moved or converted")

    @torch.no_grad()
    def _initialise(self, generators: Sequence[torch.Generator]) -> None:
        # nn.Linear's default init (kaiming_uniform(a=sqrt(5)) == U(-1/sqrt(in), 1/sqrt(in)) for the
        # weight, same bound for the bias), drawn on the CPU so a seed gives the same weights anywhere.
        for r, members, l, _fan_in, bound in self.initial_draws(len(generators)):
            weight, bias = self.layer(l)
            generator = generators[r]
            weight[members] = (torch.rand(weight[members].shape, generator=generator) * 2 - 1) * bound
            bias[members] = (torch.rand(bias[members].shape, generator=generator) * 2 - 1) * bound

    # ------------------------------------------------------------------------------ views
    def named_tensors(self) -> dict[str, torch.Tensor]:
        return dict(zip(self.tensor_names, self.tensors))

    def layer(self, l: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Layer l's ``(weight [M, in, out], bias [M, out])``, views of ``flat``."""
        return self.tensors[2 * l], self.tensors[2 * l + 1]

    # ------------------------------------------------------------------------- forward
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x [M, B, in] -> [M, B, out]``; member m only sees its own slice ``x[m]``. Differentiable."""
        for l in range(self.num_layers):
            (w0, w1), (b0, b1) = self.spans[2 * l], self.spans[2 * l + 1]
            weight = self.flat[w0:w1].view(self.shapes[2 * l])
            bias = self.flat[b0:b1].view(self.shapes[2 * l + 1])
            x = torch.baddbmm(bias.unsqueeze(1), x, weight)
            if l < self.num_layers - 1:
                x = torch.relu(x)
        return x

    @torch.no_grad()
    def predict(
        self, x: torch.Tensor, members: slice | None = None, inputs: list[torch.Tensor] | None = None
    ) -> torch.Tensor:
        """``forward`` without autograd, for ``members`` only (default all; ``x [len(members), B, in]``);
        every layer's input is appended to ``inputs`` if given (what ``backward`` needs)."""
        last = self.num_layers - 1
        for l, (weight, bias) in enumerate(self._affine):
            if members is not None:
                weight, bias = weight[members], bias[members]
            if inputs is not None:
                inputs.append(x)
            x = torch.baddbmm(bias, x, weight)
            if l < last:
                x = torch.relu(x)
        return x

    def predict_numpy(self, x: np.ndarray, members: slice | None = None) -> np.ndarray | None:
        """:meth:`predict` in numpy on the CPU (None elsewhere): cheaper per call for a batch of one (about
        35 against 55 µs for a 64x64 net here), but other float32 kernels, so results may differ from
        ``predict`` in the last bits."""
        if self._affine_arrays is None:
            return None
        last = self.num_layers - 1
        for l, (weight, bias) in enumerate(self._affine_arrays):
            if members is not None:
                weight, bias = weight[members], bias[members]
            x = np.matmul(x, weight)
            x += bias
            if l < last:
                np.maximum(x, 0.0, out=x)
        return x

    def forward_cached(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """``forward`` without autograd, also returning every layer's input (what ``backward`` needs)."""
        inputs: list[torch.Tensor] = []
        return self.predict(x, inputs=inputs), inputs

    @torch.no_grad()
    def backward(self, inputs: list[torch.Tensor], grad_out: torch.Tensor, layers: Sequence[int]) -> None:
        """Gradients of the loss w.r.t. the weights and biases of ``layers`` into :attr:`grads`, given
        ``grad_out`` = d loss / d output and the ``inputs`` of :meth:`forward_cached`.

        Autograd's formulas, kernel for kernel: for ``y = baddbmm(b, x, W)``, ``dW = x^T @ dy``,
        ``db = dy`` summed over the batch, ``dx = dy @ W^T``; for ``h = relu(z)``, ``dz = dh`` where
        ``h > 0``, else 0 (``threshold_backward``'s result). Layers not listed keep their gradient untouched (zero)
        and are not computed; the backward stops below the lowest listed layer.
        """
        grads, wanted = self.grads, set(layers)
        grad = grad_out
        for l in range(self.num_layers - 1, min(wanted, default=self.num_layers) - 1, -1):
            if l in wanted:
                torch.bmm(inputs[l].transpose(1, 2), grad, out=grads[2 * l])
                torch.sum(grad, dim=1, out=grads[2 * l + 1])
            if l > min(wanted):
                grad = torch.bmm(grad, self.layer(l)[0].transpose(1, 2))
                grad.masked_fill_(inputs[l] <= 0, 0.0)  # ReLU: the gradient passes where its output was positive

    # ------------------------------------------------------------------------- members
    def member_state(self, m: int) -> dict[str, np.ndarray]:
        """Member m's weights as numpy copies in ``nn.Linear`` layout."""
        state = {}
        for l in range(self.num_layers):
            weight, bias = self.layer(l)
            state[f"layers.{l}.weight"] = weight[m].t().contiguous().cpu().numpy()
            state[f"layers.{l}.bias"] = bias[m].cpu().clone().numpy()
        return state

    @torch.no_grad()
    def load_member_state(self, m: int, state: dict[str, np.ndarray], name_prefix: str = "") -> None:
        """Overwrite member m from ``nn.Linear``-layout tensors (all layers must be present).

        Everything is checked before anything is written (:meth:`check_member_state`).
        """
        self.check_member_state(state, name_prefix)
        for l in range(self.num_layers):
            weight, bias = self.layer(l)
            weight[m].copy_(torch.as_tensor(state[f"layers.{l}.weight"]).t())
            bias[m].copy_(torch.as_tensor(state[f"layers.{l}.bias"]))

    @torch.no_grad()
    def update_from(self, source: BatchedMLP, tau: float) -> None:
        """Move towards ``source``: exact copy when ``tau == 1`` (hard target update), else Polyak
        ``p <- p + tau * (p_source - p)``."""
        if tau == 1.0:
            self.flat.copy_(source.flat)
        else:
            self.flat.lerp_(source.flat, tau)

    @torch.no_grad()
    def clip_grad_norm_(self, max_norm: float, layers: Sequence[int] | None = None) -> torch.Tensor:
        """``torch.nn.utils.clip_grad_norm_`` (``dqn_update.clip_coefficient``) applied to each member
        separately, to the gradients of ``layers`` (default: all) in :attr:`grads`; returns the norms ``[M]``.

        One global norm over the stacked gradients would let one agent's large gradient shrink
        every other agent's step; per member, each agent is clipped as its own network would be.
        The norms are nan when the gradients are so small that nobody is clipped (CPU).
        """
        layers = range(self.num_layers) if layers is None else sorted(layers)
        tensors = [2 * l + kind for l in layers for kind in (0, 1)]
        if not tensors:
            return torch.zeros(self.num_members)
        if self.flat.device.type == "cpu" and float(self.flat_grad.norm()) < 0.99 * max_norm:
            # No member's norm can exceed the norm of all gradients together (the 1 % margin covers
            # rounding): nobody is clipped, and the exact per-member norms are not needed.
            return torch.full((self.num_members,), math.nan)
        # clip_grad_norm_'s arithmetic per member: the sum of each tensor's squares, then over tensors.
        torch.mul(self.flat_grad, self.flat_grad, out=self._squares)
        norms = torch.stack([self._squares_by_member[i].sum(1) for i in tensors]).sum(0).sqrt()
        scale = clip_coefficient(norms, max_norm)
        # A factor of exactly 1 changes nothing: skip the multiplication when nobody is clipped.
        if self.flat.device.type != "cpu" or bool((scale < 1.0).any()):
            # Untrained tensors' gradients are zero and stay zero.
            self.flat_grad.mul_(scale[self._member_of])
        return norms
