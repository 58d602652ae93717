"""The fast encoder's trainable path (two convolutions on patches, then the dense layer) as one autograd Function.

``FastEncoder`` computes its convolutions as matrix products on patches (``train/nets.py``).
Left to autograd, that path's backward does work the update does not need and lays out some
of its products badly for the CPU:

* the dense layer's input gradient is computed for all of its inputs, though only the
  window's features (the first 288 of about 600 columns) lead back to a weight;
* the first conv's weight gradient ``[16, N*49] x [N*49, 54]`` runs at half the rate of the
  same product as ``([54, N*49] x [N*49, 16])^T``;
* the second conv's output is transposed to channel-major order and back (a copy each way).

``encoder_path`` is the same function (a test checks values and gradients against
``nn.Conv2d`` and ``nn.Linear``), with the backward written out: every gradient the
parameters need and nothing else. The patches and the other dense inputs (coarse view,
side inputs) never need gradients: they are functions of the observation.
"""

from __future__ import annotations

import torch
from torch.autograd.function import once_differentiable


def _relu_grad(grad: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """``grad`` where the ReLU's output ``out`` is positive, else 0 (what ReLU's backward computes)."""
    return torch.ops.aten.threshold_backward(grad, out, 0)


class _EncoderPath(torch.autograd.Function):
    """See ``encoder_path``."""

    @staticmethod
    def forward(ctx, patches, rest, w1, b1, w2, b2, w3, b3, gather, order):
        n, cells = patches.shape[:2]
        local = len(order)
        x1 = torch.addmm(b1, patches.reshape(n * cells, -1), w1.T).relu_()  # [n * cells, c1]
        x2_in = x1.view(n, cells, -1).index_select(1, gather).view(-1, w2.shape[1])  # [n * out2^2, 9 * c1]
        x2 = torch.addmm(b2, x2_in, w2.T).relu_()  # [n * out2^2, c2]: cell-major
        w3_local = w3.index_select(1, order)  # the dense weights of the window features, cell-major
        x3_in = torch.cat([x2.view(n, local), rest], dim=1)
        out = torch.addmm(b3, x3_in, torch.cat([w3_local, w3[:, local:]], dim=1).T).relu_()
        ctx.save_for_backward(patches, x1, x2_in, x2, x3_in, out, w2, w3_local, gather, order)
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        patches, x1, x2_in, x2, x3_in, out, w2, w3_local, gather, order = ctx.saved_tensors
        n, cells = patches.shape[:2]
        local = len(order)
        g3 = _relu_grad(grad, out)  # [n, hidden]
        dw3_in = g3.T @ x3_in  # [hidden, local + rest], window columns cell-major
        dw3 = torch.empty_like(dw3_in)
        dw3[:, local:] = dw3_in[:, local:]
        dw3.index_copy_(1, order, dw3_in[:, :local])
        g2 = _relu_grad((g3 @ w3_local).view_as(x2), x2)  # [n * out2^2, c2]
        dw2 = g2.T @ x2_in
        dx1 = x1.new_zeros(n, cells, x1.shape[1]).index_add_(1, gather, (g2 @ w2).view(n, len(gather), -1))
        g1 = _relu_grad(dx1.view_as(x1), x1)  # [n * cells, c1]
        dw1 = (patches.reshape(n * cells, -1).T @ g1).T  # the faster layout of g1^T @ patches
        return None, None, dw1, g1.sum(0), dw2, g2.sum(0), dw3, g3.sum(0), None, None


def encoder_path(patches: torch.Tensor, rest: torch.Tensor, w1: torch.Tensor, b1: torch.Tensor, w2: torch.Tensor,
                 b2: torch.Tensor, w3: torch.Tensor, b3: torch.Tensor, gather: torch.Tensor,
                 order: torch.Tensor) -> torch.Tensor:
    """``relu(dense([flatten(relu(conv2(relu(conv1(window))))), rest]))`` from the window's first-conv patches.

    ``patches [n, cells, k]`` (each cell's patch, flattened as ``w1 [c1, k]`` reads it), ``rest [n, m]`` (the dense
    layer's other inputs), ``w2 [c2, 9 * c1]`` (the second conv's kernel in the order ``gather`` lays out its
    inputs: each output cell's 3x3 cells of the first conv's output, ``[out2^2 * 9]`` indices into ``cells``),
    ``w3 [hidden, c2 * out2^2 + m]`` (the window's features channel-major, as ``nn.Flatten`` gives them), and
    ``order`` (for each cell-major window feature, its channel-major column in ``w3``). Returns ``[n, hidden]``.
    """
    return _EncoderPath.apply(patches, rest, w1, b1, w2, b2, w3, b3, gather, order)
