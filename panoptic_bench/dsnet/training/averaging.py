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
from typing import Any

import torch
from torch import nn
from torch.optim.swa_utils import AveragedModel, update_bn

__all__ = ["StepAverage", "averaging_starts", "recalibrate_batchnorm"]


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
