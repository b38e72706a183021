"""K independent MLPs evaluated as one: stacked weights and batched matrix products.

A team of K DQN agents would otherwise run K small forward passes and K optimizer steps per env
step, which is dominated by Python and kernel-launch overhead. Stacking member m's layer-l weight as
``weight_l[m]`` (``[in, out]``) lets one ``torch.baddbmm`` per layer evaluate all members, and one
optimizer step update them all, while each member stays mathematically its own network: member m's
outputs depend only on ``weight_l[m]``, ``bias_l[m]``, so its gradients are exactly what a separate
``nn.Sequential(nn.Linear, nn.ReLU, ...)`` would get from the same loss.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from dqn_transfer.agents.base import check_tensor_shape


class BatchedMLP(nn.Module):
    """``num_members`` ReLU MLPs ``in_dim -> hidden... -> out_dim`` with stacked parameters.

    Parameters: ``weight_{l}`` ``[M, in, out]`` and ``bias_{l}`` ``[M, out]`` for each layer l, one
    Parameter per layer so a layer can be frozen on its own. ``member_state`` converts member m to
    the ``nn.Linear`` convention (``layers.{l}.weight`` ``[out, in]``) used in checkpoints.
    """

    def __init__(
        self,
        num_members: int,
        in_dim: int,
        hidden: Sequence[int],
        out_dim: int,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        self.num_members = num_members
        self.sizes = [in_dim, *hidden, out_dim]
        for l, (fan_in, fan_out) in enumerate(self.layer_shapes):
            # nn.Linear's default init (kaiming_uniform(a=sqrt(5)) == U(-1/sqrt(in), 1/sqrt(in)) for the
            # weight, same bound for the bias), drawn from an explicit generator so a seed fixes it.
            bound = 1.0 / math.sqrt(fan_in)
            weight = (torch.rand(num_members, fan_in, fan_out, generator=generator) * 2 - 1) * bound
            bias = (torch.rand(num_members, fan_out, generator=generator) * 2 - 1) * bound
            self.register_parameter(f"weight_{l}", nn.Parameter(weight))
            self.register_parameter(f"bias_{l}", nn.Parameter(bias))

    @property
    def layer_shapes(self) -> list[tuple[int, int]]:
        """``(in, out)`` of every layer."""
        return list(zip(self.sizes[:-1], self.sizes[1:]))

    @property
    def num_layers(self) -> int:
        return len(self.sizes) - 1

    def layer(self, l: int) -> tuple[nn.Parameter, nn.Parameter]:
        return getattr(self, f"weight_{l}"), getattr(self, f"bias_{l}")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x [M, B, in] -> [M, B, out]``; member m only sees its own slice ``x[m]``."""
        for l in range(self.num_layers):
            weight, bias = self.layer(l)
            x = torch.baddbmm(bias.unsqueeze(1), x, weight)
            if l < self.num_layers - 1:
                x = torch.relu(x)
        return x

    def member_state(self, m: int) -> dict[str, torch.Tensor]:
        """Member m's weights as detached CPU copies in ``nn.Linear`` layout."""
        state = {}
        for l in range(self.num_layers):
            weight, bias = self.layer(l)
            state[f"layers.{l}.weight"] = weight[m].detach().t().contiguous().cpu()
            state[f"layers.{l}.bias"] = bias[m].detach().cpu().clone()
        return state

    @torch.no_grad()
    def load_member_state(self, m: int, state: dict[str, torch.Tensor], name_prefix: str = "") -> None:
        """Overwrite member m from ``nn.Linear``-layout tensors (all layers must be present).

        Everything is checked before anything is written; errors name tensors as ``name_prefix +
        "layers.{l}.weight"``, the caller's naming.
        """
        for l, (fan_in, fan_out) in enumerate(self.layer_shapes):
            for kind, shape in (("weight", (fan_out, fan_in)), ("bias", (fan_out,))):
                name = f"layers.{l}.{kind}"
                if name not in state:
                    raise ValueError(f"tensor '{name_prefix}{name}' is missing")
                check_tensor_shape(name_prefix + name, state[name], shape)
        for l in range(self.num_layers):
            weight, bias = self.layer(l)
            weight[m].copy_(state[f"layers.{l}.weight"].t())
            bias[m].copy_(state[f"layers.{l}.bias"])

    @torch.no_grad()
    def update_from(self, source: BatchedMLP, tau: float) -> None:
        """Move towards ``source``: exact copy when ``tau == 1`` (hard target update), else Polyak
        ``p <- p + tau * (p_source - p)``."""
        for p, p_source in zip(self.parameters(), source.parameters()):
            if tau == 1.0:
                p.copy_(p_source)
            else:
                p.lerp_(p_source, tau)

    @torch.no_grad()
    def clip_grad_norm_(self, max_norm: float) -> torch.Tensor:
        """``torch.nn.utils.clip_grad_norm_`` applied to each member separately; returns norms ``[M]``.

        One global norm over the stacked gradients would let one agent's large gradient shrink
        every other agent's step; per member, each agent is clipped as its own network would be.
        """
        grads = [p.grad for p in self.parameters() if p.grad is not None]
        if not grads:
            return torch.zeros(self.num_members)
        norms = torch.stack([g.flatten(1).pow(2).sum(1) for g in grads]).sum(0).sqrt()
        scale = (max_norm / (norms + 1e-6)).clamp(max=1.0)
        for g in grads:
            g.mul_(scale.view(-1, *([1] * (g.dim() - 1))))
        return norms
