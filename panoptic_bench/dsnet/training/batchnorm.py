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
"""

from __future__ import annotations

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
