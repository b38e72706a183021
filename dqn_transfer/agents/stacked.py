"""What both DQN engines share: the layout of M stacked MLPs, and when subnormal Adam moments are flushed.

Member m's layer l is ``weight_l[m]`` (``[in, out]``) and ``bias_l[m]``, in both engines, and so are Adam's
moments (a checkpoint's ``optim.weight_l.exp_avg``, ...). Checkpoints use ``nn.Linear``'s convention for
the weights instead (``layers.{l}.weight`` ``[out, in]``). The numpy engine lays all tensors one after the
other in one flat buffer (``spans``), so a target sync is one copy and an Adam step a few passes over
one buffer (the torch engine keeps one Parameter per tensor, for ``torch.optim.Adam``). Nothing here
computes.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from dqn_transfer.agents.base import check_tensor_shape

SMALLEST_NORMAL = 2.0**-126  # float32's smallest normal number
FLUSH_EVERY = 50  # Adam steps between flushes of subnormal moments (kernels run 10-15x slower on them)


class StackedLayout:
    """Where the tensors of ``num_members`` ReLU MLPs ``in_dim -> hidden... -> out_dim`` lie in a flat buffer:
    ``tensor_names`` (``weight_0``, ``bias_0``, ``weight_1``, ...), their ``shapes`` and ``spans``."""

    def __init__(self, num_members: int, in_dim: int, hidden: Sequence[int], out_dim: int) -> None:
        self.num_members = num_members
        self.sizes = [in_dim, *hidden, out_dim]
        self.tensor_names: list[str] = []
        self.spans: list[tuple[int, int]] = []
        self.shapes: list[tuple[int, ...]] = []
        offset = 0
        for l, (fan_in, fan_out) in enumerate(self.layer_shapes):
            for kind, shape in (("weight", (num_members, fan_in, fan_out)), ("bias", (num_members, fan_out))):
                self.tensor_names.append(f"{kind}_{l}")
                self.shapes.append(shape)
                self.spans.append((offset, offset + math.prod(shape)))
                offset += math.prod(shape)
        self.num_parameters = offset

    @property
    def layer_shapes(self) -> list[tuple[int, int]]:
        """``(in, out)`` of every layer."""
        return list(zip(self.sizes[:-1], self.sizes[1:]))

    @property
    def num_layers(self) -> int:
        return len(self.sizes) - 1

    def views(self, flat: Any) -> list[Any]:
        """Every tensor as a view of ``flat`` (a tensor or an array of ``num_parameters`` values)."""
        return [flat[a:b].reshape(shape) for (a, b), shape in zip(self.spans, self.shapes)]

    def initial_draws(self, blocks: int) -> Iterator[tuple[int, slice, int, int, float]]:
        """The order in which initial weights are drawn: for each of ``blocks`` equal blocks of members
        (a replica's), layer by layer, ``(block, its members, layer, fan_in, bound)``; ``nn.Linear``'s
        default init draws weight then bias from U(-bound, bound), ``bound = 1 / sqrt(fan_in)``."""
        size = self.num_members // blocks
        if size * blocks != self.num_members:
            raise ValueError(f"{blocks} generators cannot split {self.num_members} members evenly")
        for r in range(blocks):
            for l, (fan_in, _) in enumerate(self.layer_shapes):
                yield r, slice(r * size, (r + 1) * size), l, fan_in, 1.0 / math.sqrt(fan_in)

    def check_member_state(self, state: Mapping[str, Any], name_prefix: str = "") -> None:
        """Refuse ``nn.Linear``-layout tensors that are not one complete member (before anything is
        written); errors name tensors as ``name_prefix + "layers.{l}.weight"``, the caller's naming."""
        for l, (fan_in, fan_out) in enumerate(self.layer_shapes):
            for kind, shape in (("weight", (fan_out, fan_in)), ("bias", (fan_out,))):
                name = f"layers.{l}.{kind}"
                if name not in state:
                    raise ValueError(f"tensor '{name_prefix}{name}' is missing")
                check_tensor_shape(name_prefix + name, state[name], shape)
