"""What both DQN engines' networks share: the layout of M stacked MLPs; and the numpy engine's Adam bookkeeping.

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


class AdamState:
    """Adam's bookkeeping for the tensors ``spans[i] = (start, end)`` of one flat buffer, with
    ``torch.optim.Adam``'s rules: state exists for a tensor from its first step on (or from
    :meth:`init_state`), and a tensor that gets no gradient in a step (a frozen layer) is skipped
    entirely, its moments and step count kept.

    :param spans: the ``[start, end)`` range of each tensor, in order and without overlap
    :param exp_avg: the first moments, one buffer like the parameters (zeros)
    :param exp_avg_sq: the second moments, likewise
    """

    def __init__(self, spans: Sequence[tuple[int, int]], exp_avg: Any, exp_avg_sq: Any) -> None:
        self.spans = list(spans)
        self.exp_avg, self.exp_avg_sq = exp_avg, exp_avg_sq
        self.steps = [0] * len(self.spans)
        self.has_state = [False] * len(self.spans)

    def moments(self, i: int, shape: Sequence[int]) -> dict[str, Any]:
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
