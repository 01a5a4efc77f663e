"""Re-estimate a network's held BatchNorm statistics on a dataset, weights unchanged.

A checkpoint's BatchNorms normalise, in eval mode, with the running averages collected while it
was trained (and fine-tunes with ``optim.freeze_bn`` keep their start's averages). To ask whether
a network's statistics or its features carry a result, :func:`recalibrate_checkpoint` replaces the
averages by those of another dataset (e.g. another synthetic world) without training: every
BatchNorm's running mean and variance are reset and recomputed as the plain average over the
given scans of each scan's batch mean and (unbiased) batch variance, by the cumulative pass that
training uses after weight averaging (:func:`panoptic_bench.dsnet.training.averaging.
recalibrate_batchnorm`, i.e. :func:`torch.optim.swa_utils.update_bn`; "precise BN", AdaBN).
Every other tensor, convolution and affine BatchNorm weights included, stays bit-identical.

Two views of a scan (``view``):

- ``"infer"``: as ``infer`` feeds it: thinned to ``augment.max_points`` by the inference
  subset (:func:`panoptic_bench.dsnet.data.density.inference_subset`, seeded by the scan) when
  the config sets ``inference.match_training_density``, otherwise whole;
- ``"train"``: as the checkpoint's training augmented it (its ``augment`` section: thinning,
  rotation, flip, scale, pose jitter, remission gain / gamma / zeroing, epoch 0 of its seed),
  without scene mixing or instance pasting, which need other scans and a bank. This is the view
  the held statistics of a trained network were collected in.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import torch
from torch import nn
from torch.nn.modules.batchnorm import _BatchNorm

from panoptic_bench.dsnet.checkpoint import Checkpoint, build_backbone, build_grid
from panoptic_bench.dsnet.data.datasets import LidarDataset, LidarSample
from panoptic_bench.dsnet.data.density import inference_max_points, inference_subset
from panoptic_bench.dsnet.data.training_set import TrainingSet
from panoptic_bench.dsnet.model.forward import backbone_forward
from panoptic_bench.dsnet.training.averaging import recalibrate_batchnorm
from panoptic_bench.errors import InputError

__all__ = ["VIEWS", "inference_view", "recalibrate_checkpoint", "view_samples"]

#: How scans are fed to the network while the statistics are measured (module docstring).
VIEWS = ("infer", "train")


def inference_view(ck: Checkpoint, sample: LidarSample) -> LidarSample:
    """``sample`` as ``infer`` feeds it to ``ck``'s network: thinned to ``augment.max_points``
    (the inference subset, seeded by the scan key) under ``inference.match_training_density``,
    else unchanged."""
    n = inference_max_points(ck.config)
    return inference_subset(sample, n)[0] if n else sample


def view_samples(
    ck: Checkpoint, dataset: LidarDataset, indices: Iterable[int], view: str = "infer"
) -> Iterable[LidarSample]:
    """The scans ``indices`` of ``dataset`` in ``view`` (one of :data:`VIEWS`), lazily."""
    if view == "infer":
        return (inference_view(ck, dataset.load(i)) for i in indices)
    if view == "train":
        aug = dataclasses.replace(ck.config.augment, mix_prob=0.0, paste_prob=0.0)
        train = TrainingSet(dataset, aug, seed=ck.config.optim.seed)
        return (train[i] for i in indices)
    raise ValueError(f"view must be one of {', '.join(VIEWS)}, got {view!r}")


def recalibrate_checkpoint(
    ck: Checkpoint, samples: Iterable[LidarSample], note: str = "", device: str = "cpu"
) -> tuple[Checkpoint, int]:
    """A copy of ``ck`` whose backbone BatchNorm statistics are re-estimated on ``samples``
    (one forward pass each, no gradients); ``ck`` itself is not changed.

    Parameters
    ----------
    ck : Checkpoint
    samples : iterable of LidarSample
        A batch of one scan each, already in the view the network should see
        (:func:`view_samples`).
    note : str
        Recorded in the new checkpoint's last ``metrics`` row.

    Returns
    -------
    (Checkpoint, int)
        The new checkpoint (no optimizer, RNG or weight-average state; one ``metrics`` row
        ``{"bn_recalibrated_on": note, "scans": n}``) and the number n of scans seen.

    Raises
    ------
    InputError
        No sample, a scan too small for batch statistics (naming it), or a BatchNorm that the
        network never calls.
    """
    net = build_backbone(ck.config, ck.class_map.num_classes)
    net.load_state_dict(ck.backbone)
    grid = build_grid(ck.config)
    seen = []

    def forward(module: nn.Module, sample: LidarSample):
        seen.append(sample.key)
        try:
            return backbone_forward(module, [sample], grid, torch.device(device))
        except ValueError as err:  # a BatchNorm given one row has no batch statistics
            raise InputError(
                f"scan {'/'.join(sample.key)} ({len(sample.xyz)} points) is too small to measure "
                f"BatchNorm statistics on ({err}); leave such scans out of --split"
            ) from None

    with torch.no_grad():
        recalibrate_batchnorm(net, samples, forward)
    if not seen:
        raise InputError("no scans to re-estimate the BatchNorm statistics on")
    norms = [n for n, m in net.named_modules() if isinstance(m, _BatchNorm)]
    state = {k: v.detach().clone() for k, v in net.state_dict().items()}
    empty = [n for n in norms if int(state[f"{n}.num_batches_tracked"]) == 0]
    if empty:
        raise InputError(
            f"BatchNorm {empty[0]} (and {len(empty) - 1} more) was never called by the network, "
            "so it has no statistics to re-estimate; this checkpoint cannot be recalibrated"
        )
    row = {"bn_recalibrated_on": note, "scans": len(seen)}
    out = dataclasses.replace(
        ck,
        backbone=state,
        shift=None if ck.shift is None else dict(ck.shift),
        optimizer=None,
        rng=None,
        average=None,
        metrics=[*ck.metrics, row],
        path=None,
    )
    return out, len(seen)
