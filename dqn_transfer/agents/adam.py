"""Adam over the named tensors of one flat parameter, a few kernels per step instead of a few per tensor.

The arithmetic is ``torch.optim.Adam``'s default path (``foreach=False``, ``fused=False``,
``amsgrad=False``, no weight decay), operation for operation, so a run gives bit-identical weights
to one trained with ``torch.optim.Adam``; the tests check it. One addition: moments that decay
below float32's normal range are set to zero every ``FLUSH_EVERY`` steps (they would slow every
kernel that reads them tenfold, and are too small to move any weight). What changes is the cost: the same
element-wise kernels run once over each stretch of neighbouring tensors instead of once per tensor,
and there is none of ``torch.optim``'s per-step Python machinery (whose first step also imports
``torch._dynamo``, seconds of start-up).

Like ``torch.optim.Adam``, a tensor that gets no gradient in a step (a frozen layer) is skipped
entirely: its moments and its step count stay as they were. State exists for a tensor from its first
step on (or from :meth:`FlatAdam.init_state`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from dqn_transfer.agents.stacked import SMALLEST_NORMAL, AdamState


class FlatAdam(AdamState):
    """Adam for the tensors ``spans[i] = (start, end)`` of ``flat``, whose gradient is ``flat_grad``.

    :param flat: the parameters, one 1-D tensor
    :param flat_grad: their gradients, same shape
    :param spans: the ``[start, end)`` range of each tensor, in order and without overlap
    :param lr: the step size
    :param betas: the moments' decay rates
    :param eps: added to the denominator
    """

    def __init__(
        self,
        flat: torch.Tensor,
        flat_grad: torch.Tensor,
        spans: Sequence[tuple[int, int]],
        lr: float,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        super().__init__(spans, torch.zeros_like(flat), torch.zeros_like(flat))
        self.flat, self.flat_grad = flat, flat_grad
        self.lr, (self.beta1, self.beta2), self.eps = lr, betas, eps
        # Views of the stretches of the last step, reused while the same tensors step together at the
        # same step counts relative to each other (what decides how they merge).
        self._stretches: list[tuple[int, tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]]] = []
        self._stretches_key: tuple[tuple[int, int], ...] | None = None

    @torch.no_grad()
    def step(self, active: Sequence[int]) -> None:
        """One Adam step for the tensors ``active`` (the others got no gradient)."""
        flush = self.count_step(active)
        key = tuple((i, self.steps[i] - self.steps[active[0]]) for i in active)
        if key != self._stretches_key:
            param = self.flat.detach()
            self._stretches = [
                (i, (param[a:b], self.flat_grad[a:b], self.exp_avg[a:b], self.exp_avg_sq[a:b]))
                for a, b, i in self.stretches(active)
            ]
            self._stretches_key = key
        for index, views in self._stretches:
            self._update(*views, self.steps[index])
        if flush:
            self._flush_subnormals()

    def _flush_subnormals(self) -> None:
        """Set moments below float32's smallest normal number to zero.

        A moment that stops receiving gradient (an input the agent no longer sees) decays towards zero
        and turns subnormal, and element-wise kernels run 10-15x slower on subnormal numbers. Such a
        moment is ~1e-38: its share of a weight's step is below that weight's last bit, so flushing it
        changes no weight.
        """
        for moment in (self.exp_avg, self.exp_avg_sq):
            moment.masked_fill_(moment.abs() < SMALLEST_NORMAL, 0.0)

    def _update(
        self, param: torch.Tensor, grad: torch.Tensor, exp_avg: torch.Tensor, exp_avg_sq: torch.Tensor, step: int
    ) -> None:
        # torch.optim.adam._single_tensor_adam, the non-capturable branch, on one stretch.
        exp_avg.lerp_(grad, 1 - self.beta1)
        exp_avg_sq.mul_(self.beta2).addcmul_(grad, grad, value=1 - self.beta2)
        # torch.optim keeps ``step`` as a float32 tensor and reads it back as a Python float.
        step_value = float(step)
        bias_correction1 = 1 - self.beta1**step_value
        bias_correction2 = 1 - self.beta2**step_value
        step_size = self.lr / bias_correction1
        bias_correction2_sqrt = bias_correction2**0.5
        # torch's CPU sqrt takes a slow path on exact zeros (15x; inputs never seen leave many), so the
        # root is taken of at least SMALLEST_NORMAL. That changes no denominator: its root over
        # bias_correction2_sqrt (>= 0.03) is below half the last bit of eps, which it is added to.
        denom = (exp_avg_sq.clamp_min(SMALLEST_NORMAL).sqrt_() / bias_correction2_sqrt).add_(self.eps)
        param.addcdiv_(exp_avg, denom, value=-step_size)
