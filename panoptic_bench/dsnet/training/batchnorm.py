"""Hold a network's BatchNorm statistics through training (``optim.freeze_bn``).

With ``optim.batch_size: 1`` every BatchNorm of the backbone normalises a training scan with that
scan's own statistics, while inference uses running averages of the last few dozen training
scans (momentum 0.1): the prediction then depends on which scans happened to come last, and on
real scans that draw alone moves one network's mIoU by several points (issue 13, session 37).
Held BatchNorms normalise with the running statistics they started the stage with, in training
as at inference, and never update them; their affine weight and bias still train (the
``FrozenBatchNorm`` of detection fine-tuning, e.g. detectron2). Which statistics are held is
``optim.freeze_bn_from``: the start checkpoint's, or (:func:`measure_held_statistics`) the
equal-weight mean over every training scan of the stage's first epoch, measured once with the
start weights, so the normalisation describes the world being trained on rather than the last
scans another training happened to see.

``optim.bn_noise`` = sigma > 0 (:func:`statistics_noise`) restyles, in training only, every held
BatchNorm's input per step: in the units of the held statistics each channel is scaled by
1 + sigma * a and shifted by sigma * b (a, b standard normal, drawn per channel and step), so the
network learns under the kind of shift of activation statistics that another domain brings (the
feature-statistics augmentation of DSU, Li et al., ICLR 2022, with a fixed spread).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import TYPE_CHECKING

import torch
from torch import nn

from panoptic_bench.dsnet.model.forward import backbone_forward
from panoptic_bench.dsnet.training.averaging import recalibrate_batchnorm

if TYPE_CHECKING:
    from panoptic_bench.dsnet.training.train import TrainContext


def hold_batchnorm_statistics(module: nn.Module) -> int:
    """Put every BatchNorm of ``module`` in eval mode; returns how many there are.

    Call after ``module.train()``: the rest of the network keeps training behaviour (dropout and
    the like), the BatchNorms normalise with and keep their ``running_mean`` / ``running_var``.
    """
    held = 0
    for sub in module.modules():
        if isinstance(sub, nn.modules.batchnorm._BatchNorm):
            sub.eval()
            held += 1
    return held


def restyle(
    x: torch.Tensor,
    mean: torch.Tensor,
    std: torch.Tensor,
    scale: torch.Tensor,
    shift: torch.Tensor,
) -> torch.Tensor:
    """Scale and shift ``x``'s channels about ``mean`` in units of ``std``.

    Parameters
    ----------
    x : (n, C) float tensor
    mean, std : (C,) float tensors
        The statistics a BatchNorm normalises with.
    scale, shift : (C,) float tensors

    Returns
    -------
    (n, C) tensor ``mean + (x - mean) * scale + shift * std``: normalised with ``mean`` and
    ``std`` it is ``x``'s normalised value times ``scale`` plus ``shift``.
    """
    return mean + (x - mean) * scale + shift * std


@contextlib.contextmanager
def statistics_noise(module: nn.Module, sigma: float) -> Iterator[int]:
    """While active, every BatchNorm of ``module`` restyles its input with fresh noise per call.

    Each call draws a, b ~ N(0, 1) per channel from torch's global generator and feeds
    ``restyle(x, running_mean, sqrt(running_var + eps), 1 + sigma * a, sigma * b)`` to the
    BatchNorm (meant for held BatchNorms, which normalise with those running statistics).
    ``sigma`` = 0 registers nothing. Yields the number of BatchNorms restyled; the hooks are
    removed on exit, also on error.
    """

    def hook(bn: nn.Module, args: tuple) -> tuple:
        x = args[0]
        a, b = torch.randn(2, x.shape[1], dtype=x.dtype, device=x.device) * sigma
        std = torch.sqrt(bn.running_var + bn.eps)
        return (restyle(x, bn.running_mean, std, 1 + a, b), *args[1:])

    norms = [m for m in module.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    handles = [m.register_forward_pre_hook(hook) for m in norms] if sigma > 0 else []
    try:
        yield len(handles)
    finally:
        for h in handles:
            h.remove()


def measure_held_statistics(backbone: nn.Module, ctx: TrainContext, epoch: int = 0) -> int:
    """Re-measure ``backbone``'s BatchNorm statistics over every training scan of ``epoch``.

    One cumulative pass (:func:`recalibrate_batchnorm`: each BatchNorm's running mean and
    variance become the equal-weight mean of the scans' batch statistics), with the scans as
    the stage's ``epoch`` augments them, in index order; every rank measures all scans, so all
    ranks hold the same statistics. Parameters and the global random state are unchanged (a
    resumed stage reproduces the run bit for bit). Returns the number of scans measured.
    """
    from tqdm import tqdm

    n = len(ctx.train_set)
    ctx.train_set.set_epoch(epoch)
    scans = (ctx.train_set[i] for i in tqdm(range(n), desc="BatchNorm", disable=not ctx.progress))
    dev = ctx.info.device
    rng = torch.get_rng_state()
    recalibrate_batchnorm(backbone, scans, lambda net, s: backbone_forward(net, [s], ctx.grid, dev))
    torch.set_rng_state(rng)
    return n
