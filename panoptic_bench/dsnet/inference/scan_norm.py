"""Per-scan BatchNorm statistics at test time (``inference.bn_stats = "scan"``).

Every synthetic-only recipe trains with one scan per batch, so in training each BatchNorm
normalises with the statistics of the scan it sees. In eval mode a BatchNorm uses the running
averages collected in training instead; on data from another domain (real scans for a model
trained on synthetic worlds) those averages no longer describe the features.
:func:`scan_statistics` makes every BatchNorm of a model normalise with the statistics of the
input it is given, exactly as in training, without touching the running averages and without
carrying anything from one call to the next: the prediction of a scan depends on that scan only
(prediction-time BatchNorm; Li et al. 2016 "Revisiting batch normalization for practical domain
adaptation", Nado et al. 2020 "Evaluating prediction-time batch normalization").

A layer that receives a single row (a scan so small that one level of the U-Net holds one site)
has no batch statistics: that layer uses its running averages for that call.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from torch import nn
from torch.nn.modules.batchnorm import _BatchNorm

__all__ = ["scan_statistics"]


@contextlib.contextmanager
def scan_statistics(*models: nn.Module, enabled: bool = True) -> Iterator[None]:
    """Within the block, the BatchNorms of ``models`` normalise with their input's statistics.

    The running mean / variance buffers are detached for the block (an eval-mode BatchNorm
    without them normalises with the batch's mean and biased variance and updates nothing) and
    put back, unchanged, when the block ends, also on an exception. ``enabled=False`` is a no-op.
    The inference shortcuts of :mod:`panoptic_bench.dsnet.sparse.fused` (which fold the running
    averages into the convs) step aside while a BatchNorm has no running statistics.

    Parameters
    ----------
    *models : torch.nn.Module
        Models in eval mode (training-mode BatchNorms already use batch statistics).
    enabled : bool
    """
    if not enabled:
        yield
        return
    norms = [m for model in models for m in model.modules() if isinstance(m, _BatchNorm)]
    norms = [m for m in norms if m.running_mean is not None and m.running_var is not None]
    saved = [(m.running_mean, m.running_var) for m in norms]
    handles = []
    for norm, (mean, var) in zip(norms, saved):
        handles.append(norm.register_forward_pre_hook(_single_row_guard(mean, var)))
        handles.append(norm.register_forward_hook(_detach_after))
        norm.running_mean, norm.running_var = None, None
    try:
        yield
    finally:
        for handle in handles:
            handle.remove()
        for norm, (mean, var) in zip(norms, saved):
            norm.running_mean, norm.running_var = mean, var


def _single_row_guard(mean: torch.Tensor, var: torch.Tensor):
    """Pre-hook: a call with fewer than two rows gets the running averages back for that call."""

    def hook(norm: _BatchNorm, args: tuple) -> None:
        if args[0].shape[0] < 2:
            norm.running_mean, norm.running_var = mean, var

    return hook


def _detach_after(norm: _BatchNorm, args: tuple, output: torch.Tensor) -> None:
    """Forward hook: the running averages leave again after a single-row call."""
    norm.running_mean, norm.running_var = None, None
