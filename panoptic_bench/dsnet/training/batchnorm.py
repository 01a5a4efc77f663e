"""Hold a network's BatchNorm statistics through training (``optim.freeze_bn``).

With ``optim.batch_size: 1`` every BatchNorm of the backbone normalises a training scan with that
scan's own statistics, while inference uses running averages of the last few dozen training
scans (momentum 0.1): the prediction then depends on which scans happened to come last, and on
real scans that draw alone moves one network's mIoU by several points (issue 13, session 37).
Held BatchNorms normalise with the running statistics they started the stage with, in training
as at inference, and never update them; their affine weight and bias still train (the
``FrozenBatchNorm`` of detection fine-tuning, e.g. detectron2).
"""

from __future__ import annotations

from torch import nn


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
