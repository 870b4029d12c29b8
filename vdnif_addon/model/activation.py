"""The MLPs' ReLU, in place, on bfloat16 activations as an integer operation on their bits.

A bfloat16 number read as an int16 is negative exactly when its sign bit is set: from -32768
(-0) to -129 the negative numbers (-128 is -inf), from -127 to -1 the NaNs with the sign bit
set. Keeping the values above -128 and setting the others to 0 is then ReLU: negatives and
-inf become +0, positives, +0, +inf and every NaN stay. torch's ReLU on bfloat16 converts to
float32 and back, and took several times as long as this integer threshold on a batch's
activations, about as long as the product before it (``docs/performance.md``).
The result equals torch's bit for bit but for -0, which torch keeps and this makes +0 (the
same number to every later operation but a sign test), and for a NaN's bits (torch writes a
NaN of its own, this keeps the one it was given). Other dtypes and devices take
torch's ReLU (float32's integer threshold is no faster; on CUDA either is bound by memory).

The backward is ReLU's own (``threshold_backward`` of the output, as torch's ReLU takes it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import torch
import torch.nn.functional as F
from torch import nn

if TYPE_CHECKING:
    from jaxtyping import Float

NEGATIVE_BITS = -128
"""bfloat16 -inf read as an int16: every value at or below it is a negative number or -0."""


def _relu_bits(x: Float[torch.Tensor, "..."]) -> Float[torch.Tensor, "..."]:
    """ReLU of a bfloat16 tensor in place, by its bits (the module's docstring says why)."""
    F.threshold_(x.view(torch.int16), NEGATIVE_BITS, 0)
    return x


class _ReLUBits(torch.autograd.Function):
    """``_relu_bits`` with ReLU's gradient: the output's gradient where the output is above
    0, else 0."""

    @staticmethod
    def forward(ctx: Any, x: Float[torch.Tensor, "..."]) -> Float[torch.Tensor, "..."]:
        _relu_bits(x)
        ctx.mark_dirty(x)
        ctx.save_for_backward(x)
        return x

    @staticmethod
    def backward(ctx: Any, grad: Float[torch.Tensor, "..."]) -> Float[torch.Tensor, "..."]:
        (out,) = ctx.saved_tensors
        return torch.ops.aten.threshold_backward(grad, out, 0)


class ReLU(nn.Module):
    """ReLU in place: bfloat16 activations on the CPU by their bits, others by torch's."""

    def forward(self, x: Float[torch.Tensor, "..."]) -> Float[torch.Tensor, "..."]:
        if x.dtype != torch.bfloat16 or x.device.type != "cpu":
            return F.relu(x, inplace=True)
        if torch.is_grad_enabled() and x.requires_grad:
            return _ReLUBits.apply(x)
        return _relu_bits(x)
