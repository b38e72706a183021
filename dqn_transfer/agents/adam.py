"""Adam over the named tensors of one flat parameter, a few kernels per step instead of a few per tensor.

The arithmetic is ``torch.optim.Adam``'s default path (``foreach=False``, ``fused=False``,
``amsgrad=False``, no weight decay), operation for operation, so a run gives bit-identical weights
to one trained with ``torch.optim.Adam``; the tests check it. What changes is the cost: the same
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


class FlatAdam:
    """Adam for the tensors ``spans[i] = (start, end)`` of ``flat``, whose gradient is ``flat_grad``.

    :param flat: the parameters, one 1-D tensor
    :param flat_grad: their gradients, same shape
    :param spans: the ``[start, end)`` range of each tensor, in order and without overlap
    :param lr: the step size
    :param betas: the moments' decay rates
    :param eps: added to the denominator
    """

    def __init__(self, flat: torch.Tensor, flat_grad: torch.Tensor, spans: Sequence[tuple[int, int]],
                 lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        self.flat, self.flat_grad = flat, flat_grad
        self.spans = list(spans)
        self.lr, (self.beta1, self.beta2), self.eps = lr, betas, eps
        self.exp_avg = torch.zeros_like(flat)
        self.exp_avg_sq = torch.zeros_like(flat)
        self.steps = [0] * len(self.spans)
        self.has_state = [False] * len(self.spans)

    def init_state(self, i: int) -> None:
        """Give tensor i the state Adam creates at its first step (zero moments, step 0), if it has none."""
        if not self.has_state[i]:
            a, b = self.spans[i]
            self.exp_avg[a:b] = 0.0
            self.exp_avg_sq[a:b] = 0.0
            self.steps[i] = 0
            self.has_state[i] = True

    @torch.no_grad()
    def step(self, active: Sequence[int]) -> None:
        """One Adam step for the tensors ``active`` (the others got no gradient)."""
        for i in active:
            self.init_state(i)
            self.steps[i] += 1
        for start, end, step in self._stretches(sorted(active)):
            self._update(slice(start, end), step)

    def _stretches(self, active: list[int]) -> list[tuple[int, int, int]]:
        """Neighbouring active tensors at the same step count, merged into ``(start, end, step)``."""
        stretches: list[tuple[int, int, int]] = []
        for i in active:
            (a, b), step = self.spans[i], self.steps[i]
            if stretches and stretches[-1][1] == a and stretches[-1][2] == step:
                stretches[-1] = (stretches[-1][0], b, step)
            else:
                stretches.append((a, b, step))
        return stretches

    def _update(self, span: slice, step: int) -> None:
        # torch.optim.adam._single_tensor_adam, the non-capturable branch, on one stretch.
        param, grad = self.flat.detach()[span], self.flat_grad[span]
        exp_avg, exp_avg_sq = self.exp_avg[span], self.exp_avg_sq[span]
        exp_avg.lerp_(grad, 1 - self.beta1)
        exp_avg_sq.mul_(self.beta2).addcmul_(grad, grad, value=1 - self.beta2)
        # torch.optim keeps ``step`` as a float32 tensor and reads it back as a Python float.
        step_value = float(step)
        bias_correction1 = 1 - self.beta1**step_value
        bias_correction2 = 1 - self.beta2**step_value
        step_size = self.lr / bias_correction1
        bias_correction2_sqrt = bias_correction2**0.5
        denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
        param.addcdiv_(exp_avg, denom, value=-step_size)
