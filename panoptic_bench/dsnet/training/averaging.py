"""Weight averaging along one training run (SWA: Izmailov et al., UAI 2018; dense, per step, as
in SWAD: Cha et al., NeurIPS 2021).

With ``optim.swa_epochs`` = k > 0, the semantic and offset stages keep the equal-weight mean of
the backbone's parameters over every optimiser step of their last k epochs
(:class:`torch.optim.swa_utils.AveragedModel`). After the last step the backbone takes the mean
weights and its BatchNorm statistics are measured again on training scans
(:func:`torch.optim.swa_utils.update_bn`, one cumulative pass, no gradients), because running
statistics collected along the path do not belong to the averaged weights. The stage then
validates and saves that network; the running mean is stored in the stage checkpoint
(``average``) while the stage is unfinished, so ``--resume`` continues it bit for bit.

Flat minima found this way are the usual remedy for a model that must work on data unlike its
training data; the synthetic-to-real gap of issue 13 is such a case.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

import torch
from torch import nn
from torch.optim.swa_utils import AveragedModel, update_bn

from panoptic_bench.dsnet import distributed as ddp
from panoptic_bench.dsnet.model.forward import backbone_forward
from panoptic_bench.dsnet.training.resume import checkpoint_path
from panoptic_bench.errors import InputError

if TYPE_CHECKING:
    from panoptic_bench.dsnet.checkpoint import Checkpoint
    from panoptic_bench.dsnet.training.train import TrainContext

__all__ = [
    "StepAverage",
    "averaging_starts",
    "finish_stage_average",
    "recalibrate_batchnorm",
    "stage_average",
]


def averaging_starts(total: int, swa_epochs: int) -> int:
    """0-based first epoch of a ``total``-epoch stage whose steps enter the mean.

    ``swa_epochs`` = 0 (off) gives ``total`` (no epoch); more epochs than the stage has
    average the whole stage.
    """
    if swa_epochs <= 0:
        return total
    return max(total - swa_epochs, 0)


class StepAverage:
    """Equal-weight running mean of a module's parameters, one term per optimiser step.

    Parameters
    ----------
    module : nn.Module
        The network being trained; a copy holds the mean (buffers are not averaged).
    state : dict, optional
        :meth:`state_dict` of an earlier average of the same network (resume).
    """

    def __init__(self, module: nn.Module, state: dict[str, Any] | None = None):
        self.model = AveragedModel(module)
        if state is not None:
            self.model.load_state_dict(state)

    @property
    def count(self) -> int:
        """Steps averaged so far."""
        return int(self.model.n_averaged)

    def update(self, module: nn.Module) -> None:
        """Add the current parameters of ``module`` to the mean."""
        self.model.update_parameters(module)

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Tensors of the mean (CPU), for the stage checkpoint."""
        return {k: v.detach().cpu() for k, v in self.model.state_dict().items()}

    def copy_to(self, module: nn.Module) -> None:
        """Overwrite the parameters of ``module`` with the mean (buffers untouched).

        Raises
        ------
        ValueError
            When no step has been averaged.
        """
        if self.count == 0:
            raise ValueError("no optimiser step was averaged")
        with torch.no_grad():
            for mean, param in zip(
                self.model.module.parameters(), module.parameters(), strict=True
            ):
                param.copy_(mean)


class _Forward(nn.Module):
    """Adapter: ``update_bn`` calls ``model(x)``; here ``x`` is one training sample."""

    def __init__(self, backbone: nn.Module, forward: Callable[[nn.Module, Any], Any]):
        super().__init__()
        self.backbone = backbone
        self._forward = forward

    def forward(self, sample: Any) -> Any:
        return self._forward(self.backbone, sample)


def recalibrate_batchnorm(
    backbone: nn.Module, samples: Iterable[Any], forward: Callable[[nn.Module, Any], Any]
) -> None:
    """Re-measure every BatchNorm's running mean and variance of ``backbone`` on ``samples``.

    Parameters
    ----------
    backbone : nn.Module
        Its BatchNorm statistics are reset and replaced by the equal-weight mean of each
        sample's batch statistics; its parameters are not changed; it is left in the
        train / eval mode it had.
    samples : iterable
        One forward batch each (here one training scan).
    forward : callable
        ``forward(backbone, sample)`` runs the network on one sample.
    """
    was_training = backbone.training
    update_bn(((s,) for s in samples), _Forward(backbone, forward))
    backbone.train(was_training)


def stage_average(
    stage: str, backbone: nn.Module, own: Checkpoint | None, ctx: TrainContext, total: int
) -> tuple[StepAverage | None, int]:
    """The stage's weight average (None when ``optim.swa_epochs`` is 0 or in stage ``ds``)
    and the first epoch it takes steps from; resumed from ``own.average`` when stored."""
    if stage == "ds" or ctx.cfg.optim.swa_epochs <= 0:
        return None, total
    if own is not None and own.epoch < total and any("swa_steps" in r for r in own.metrics):
        raise InputError(
            f"this {stage} stage already ended on its weight average at epoch {own.epoch}; "
            "training on would start from the mean: train a new run with the full --epochs",
            checkpoint_path(ctx.run_dir, stage),
        )
    stored = None if own is None else own.average
    return StepAverage(backbone, stored), averaging_starts(total, ctx.cfg.optim.swa_epochs)


def finish_stage_average(average: StepAverage, backbone: nn.Module, ctx: TrainContext, epoch: int):
    """Give ``backbone`` the mean weights and re-measure its BatchNorm statistics on this
    rank's training scans of ``epoch`` (the first ``optim.swa_bn_scans`` of them; 0: all)."""
    from tqdm import tqdm

    average.copy_to(backbone)
    order = ddp.shard_order(len(ctx.train_set), epoch, ctx.cfg.optim.seed, ctx.info, shuffle=True)
    if ctx.cfg.optim.swa_bn_scans > 0:
        order = order[: ctx.cfg.optim.swa_bn_scans]
    ctx.train_set.set_epoch(epoch)
    scans = (ctx.train_set[i] for i in tqdm(order, desc="BatchNorm", disable=not ctx.progress))
    dev = ctx.info.device
    recalibrate_batchnorm(backbone, scans, lambda net, s: backbone_forward(net, [s], ctx.grid, dev))
