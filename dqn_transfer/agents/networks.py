"""M independent MLPs evaluated as one: stacked weights, batched matrix products.

A team of K DQN agents (and R replicas of a team) would otherwise run M small forward passes and M
optimizer steps per env step, which is dominated by Python and kernel-launch overhead. Stacking
member m's layer-l weight as ``weight_l[m]`` (``[in, out]``) lets one ``torch.baddbmm`` per layer
evaluate all members, while each member stays mathematically its own network: member m's outputs
depend only on ``weight_l[m]``, ``bias_l[m]``, so autograd gives it exactly the gradients a separate
``nn.Sequential(nn.Linear, nn.ReLU, ...)`` would get from the same loss.

The parameters are one ``nn.Parameter`` per stacked tensor (``weight_0``, ``bias_0``, ``weight_1``, ...),
so ``torch.optim.Adam`` keeps one state per tensor, shaped as the tensor (a frozen layer is one
Parameter without gradient), and a target sync is one ``foreach`` copy or lerp over the list.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from dqn_transfer.agents.dqn_update import clip_coefficient
from dqn_transfer.agents.stacked import StackedLayout


class BatchedMLP(nn.Module, StackedLayout):
    """``num_members`` ReLU MLPs ``in_dim -> hidden... -> out_dim`` with stacked parameters.

    Parameters ``weight_{l}`` ``[M, in, out]`` and ``bias_{l}`` ``[M, out]`` for each layer l (``tensors``,
    :meth:`layer`, :meth:`named_tensors`, in ``tensor_names`` order). ``member_state`` converts member m to
    the ``nn.Linear`` convention (``layers.{l}.weight`` ``[out, in]``) used in checkpoints.

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
        self.tensors: list[torch.Tensor] = []
        for name, shape in zip(self.tensor_names, self.shapes):
            parameter = nn.Parameter(torch.zeros(shape, device=device))
            self.register_parameter(name, parameter)
            self.tensors.append(parameter)
        # The weights as numpy arrays sharing their memory (CPU; biases as [M, 1, out] rows), for predict_numpy.
        self._affine_arrays = (
            [(w.detach().numpy(), b.detach().unsqueeze(1).numpy()) for w, b in map(self.layer, range(self.num_layers))]
            if torch.device(device).type == "cpu"
            else None
        )
        if generators:
            self._initialise(generators)

    def _apply(self, fn, recurse=True):
        # .to(), .cuda(), .double() ... would give the parameters new storage behind predict_numpy's back.
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
        """Layer l's ``(weight [M, in, out], bias [M, out])``."""
        return self.tensors[2 * l], self.tensors[2 * l + 1]

    # ------------------------------------------------------------------------- forward
    def forward(self, x: torch.Tensor, members: slice | None = None) -> torch.Tensor:
        """``x [len(members), B, in] -> [len(members), B, out]`` for ``members`` (default all); member m only
        sees its own slice of ``x``."""
        last = self.num_layers - 1
        for l in range(self.num_layers):
            weight, bias = self.layer(l)
            if members is not None:
                weight, bias = weight[members], bias[members]
            x = torch.baddbmm(bias.unsqueeze(1), x, weight)
            if l < last:
                x = torch.relu(x)
        return x

    def predict_numpy(self, x: np.ndarray, members: slice | None = None) -> np.ndarray | None:
        """:meth:`forward` in numpy on the CPU (None elsewhere): cheaper per call for a batch of one (about
        35 against 55 µs for a 64x64 net here), but other float32 kernels, so results may differ from
        ``forward`` in the last bits."""
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

    # ------------------------------------------------------------------------- members
    def member_state(self, m: int) -> dict[str, np.ndarray]:
        """Member m's weights as numpy copies in ``nn.Linear`` layout."""
        state = {}
        for l in range(self.num_layers):
            weight, bias = self.layer(l)
            state[f"layers.{l}.weight"] = weight[m].detach().t().contiguous().cpu().numpy()
            state[f"layers.{l}.bias"] = bias[m].detach().cpu().clone().numpy()
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
    def update_from(self, source: BatchedMLP, tau: float, times: int = 1) -> None:
        """Move towards ``source``, ``times`` target syncs in a row: exact copy when ``tau == 1`` (hard target
        update), else Polyak ``p <- p + tau * (p_source - p)`` ``times`` times."""
        if tau == 1.0:
            torch._foreach_copy_(self.tensors, source.tensors)
        else:
            for _ in range(times):
                torch._foreach_lerp_(self.tensors, source.tensors, tau)

    @torch.no_grad()
    def clip_grad_norm_(self, max_norm: float) -> None:
        """``torch.nn.utils.clip_grad_norm_`` (``dqn_update.clip_coefficient``) applied to each member
        separately, over the parameters that have a gradient (a frozen layer has none).

        One global norm over the stacked gradients would let one agent's large gradient shrink
        every other agent's step; per member, each agent (or each replica's shared network) is
        clipped as its own network would be.
        """
        grads = [tensor.grad for tensor in self.tensors if tensor.grad is not None]
        if not grads:
            return
        # clip_grad_norm_'s arithmetic per member: the sum of each tensor's squares, then over tensors.
        norms = torch.stack([grad.square().flatten(1).sum(1) for grad in grads]).sum(0).sqrt()
        scale = clip_coefficient(norms, max_norm)
        torch._foreach_mul_(grads, [scale.view(-1, *[1] * (grad.dim() - 1)) for grad in grads])
