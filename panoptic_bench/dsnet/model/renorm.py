"""Batch Renormalization (Ioffe 2017) for the backbone's BatchNorms (``model.norm: renorm``).

Training with one scan a step (``optim.batch_size: 1``) normalises every scan with its own
statistics, while inference uses running averages: the network never meets in training the
normalisation it is used with. Batch Renormalization corrects each training batch's normalised
values towards the running statistics,

    x_hat = (x - mean_B) / std_B * r + d,   r = std_B / std,   d = (mean_B - mean) / std,

with ``r`` clipped to [1 / r_max, r_max], ``d`` to [-d_max, d_max] and both treated as constants
by the gradient. Within the limits the forward pass equals the inference one, ``(x - mean) /
std``, and the running statistics keep following the data (momentum as BatchNorm). In eval mode
it *is* BatchNorm: state-dict keys and inference are unchanged, so a BatchNorm checkpoint
initialises a renormalised network and back.
"""

from __future__ import annotations

import torch
from torch import nn

from panoptic_bench.dsnet.config import NORMS  # noqa: F401 - re-exported

#: Ioffe's limits at the end of his warm-up; used from the first step here (the networks start
#: from trained checkpoints whose running statistics are already meaningful).
R_MAX = 3.0
D_MAX = 5.0


def batch_renorm(
    x: torch.Tensor,
    running_mean: torch.Tensor,
    running_var: torch.Tensor,
    weight: torch.Tensor | None,
    bias: torch.Tensor | None,
    momentum: float = 0.1,
    eps: float = 1e-5,
    r_max: float = R_MAX,
    d_max: float = D_MAX,
) -> torch.Tensor:
    """Training-mode Batch Renormalization of ``x`` (n, channels), float.

    ``running_mean`` / ``running_var`` (channels,) are read first, then updated in place with
    ``momentum`` from this batch (unbiased variance, as :class:`torch.nn.BatchNorm1d`).
    """
    if x.dim() != 2 or x.shape[0] < 2:
        raise ValueError(f"batch_renorm needs (n >= 2, channels) values, got {tuple(x.shape)}")
    mean = x.mean(0)
    var = x.var(0, unbiased=False)
    std = torch.sqrt(var + eps)
    with torch.no_grad():
        run_std = torch.sqrt(running_var + eps)
        r = (std / run_std).clamp(1.0 / r_max, r_max)
        d = ((mean - running_mean) / run_std).clamp(-d_max, d_max)
    out = (x - mean) / std * r + d
    if weight is not None:
        out = out * weight + bias
    with torch.no_grad():
        n = x.shape[0]
        running_mean.mul_(1.0 - momentum).add_(mean.detach(), alpha=momentum)
        running_var.mul_(1.0 - momentum).add_(var.detach() * (n / (n - 1)), alpha=momentum)
    return out


class BatchRenorm1d(nn.BatchNorm1d):
    """:class:`torch.nn.BatchNorm1d` with Batch Renormalization in training mode."""

    def __init__(self, num_features: int, r_max: float = R_MAX, d_max: float = D_MAX, **kw):
        super().__init__(num_features, **kw)
        self.r_max = float(r_max)
        self.d_max = float(d_max)

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, r_max={self.r_max}, d_max={self.d_max}"

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training or self.running_mean is None:
            return super().forward(x)
        self.num_batches_tracked.add_(1)
        return batch_renorm(
            x,
            self.running_mean,
            self.running_var,
            self.weight,
            self.bias,
            self.momentum if self.momentum is not None else 0.1,
            self.eps,
            self.r_max,
            self.d_max,
        )


def renormalise_batchnorms(module: nn.Module) -> int:
    """Replace every plain ``BatchNorm1d`` inside ``module`` by a :class:`BatchRenorm1d`.

    Parameters and buffers are carried over unchanged. Returns how many were replaced.
    """
    replaced = 0
    for name, child in list(module.named_children()):
        if type(child) is nn.BatchNorm1d:
            new = BatchRenorm1d(
                child.num_features,
                eps=child.eps,
                momentum=child.momentum,
                affine=child.affine,
                track_running_stats=child.track_running_stats,
            )
            new.load_state_dict(child.state_dict())
            if child.affine:
                new.to(child.weight.device)
            new.train(child.training)
            setattr(module, name, new)
            replaced += 1
        else:
            replaced += renormalise_batchnorms(child)
    return replaced
