"""Weight averaging of fine-tuned checkpoints ("model soup", Wortsman et al., ICML 2022).

Checkpoints of one network fine-tuned from the same start (e.g. the seeds of one recipe, each
ending on a cosine schedule) usually sit in one basin of the loss; the average of their weights
is one network of one network's inference cost that often predicts like the ensemble of its
ingredients. :func:`average_checkpoints` averages every floating-point tensor of the backbone and
of the dynamic-shifting head, BatchNorm running statistics included; integer tensors (BatchNorm's
``num_batches_tracked``) are taken from the first checkpoint. No data is read.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch

from panoptic_bench.dsnet.checkpoint import Checkpoint, load_checkpoint
from panoptic_bench.errors import InputError

__all__ = ["average_checkpoints", "average_states"]


def average_states(
    states: Sequence[dict[str, torch.Tensor]], weights: Sequence[float]
) -> dict[str, torch.Tensor]:
    """Weighted mean of state dicts with the same keys and shapes.

    Parameters
    ----------
    states : sequence of dict[str, Tensor]
        State dicts of one module; every tensor of the first must be in each, same shape.
    weights : sequence of float
        One non-negative weight per state, summing to 1.

    Returns
    -------
    dict[str, Tensor]
        Floating-point tensors: ``sum_i weights[i] * states[i][key]`` computed in float64 and
        cast back to the first state's dtype; other tensors copied from ``states[0]``.
    """
    out: dict[str, torch.Tensor] = {}
    for key, first in states[0].items():
        if not first.is_floating_point():
            out[key] = first.clone()
            continue
        acc = torch.zeros(first.shape, dtype=torch.float64)
        for w, state in zip(weights, states):
            acc += w * state[key].to(torch.float64)
        out[key] = acc.to(first.dtype)
    return out


def average_checkpoints(
    paths: Sequence[str | Path], weights: Sequence[float] | None = None
) -> Checkpoint:
    """The weight average of two or more checkpoints of one network.

    Parameters
    ----------
    paths : sequence of str or Path
        Checkpoints written by ``train`` (or shipped); all of one stage, one class map and one
        network (equal ``grid``, ``model`` and ``dynamic_shift`` config sections, equal tensor
        names and shapes). The training sections (optimizer, seed, schedule) may differ.
    weights : sequence of float, optional
        One positive weight per checkpoint (normalised to sum 1); default uniform.

    Returns
    -------
    Checkpoint
        Stage, epoch, config and class map of the first checkpoint, the averaged weights, no
        optimizer or RNG state, and one ``metrics`` row naming the ingredients.

    Raises
    ------
    InputError
        Fewer than two checkpoints, a bad weight, or a checkpoint of another stage, class map or
        network than the first (the message names the file and what differs).
    """
    paths = [Path(p) for p in paths]
    if len(paths) < 2:
        raise InputError(f"averaging needs at least two checkpoints, got {len(paths)}")
    if weights is None:
        weights = [1.0] * len(paths)
    weights = [float(w) for w in weights]
    if len(weights) != len(paths):
        raise InputError(f"{len(weights)} weights for {len(paths)} checkpoints")
    if not all(0.0 < w < float("inf") for w in weights):  # NaN fails both comparisons
        raise InputError(f"weights must be positive finite numbers, got {weights}")
    total = sum(weights)
    weights = [w / total for w in weights]
    cks = [load_checkpoint(p) for p in paths]
    first = cks[0]
    for ck, path in zip(cks[1:], paths[1:]):
        _check_same_network(first, ck, paths[0], path)
    shift = None
    if first.shift is not None:
        shift = average_states([ck.shift for ck in cks], weights)
    return Checkpoint(
        stage=first.stage,
        epoch=first.epoch,
        config=first.config,
        class_map=first.class_map,
        backbone=average_states([ck.backbone for ck in cks], weights),
        shift=shift,
        class_weights=first.class_weights,
        metrics=[
            {
                "averaged_from": "; ".join(str(p) for p in paths),
                "weights": "; ".join(f"{w:.4g}" for w in weights),
            }
        ],
    )


def _check_same_network(a: Checkpoint, b: Checkpoint, path_a: Path, path_b: Path) -> None:
    """Raise :class:`InputError` naming ``path_b`` when it is not the network of ``path_a``."""
    if b.stage != a.stage:
        raise InputError(f"stage {b.stage!r}, but {path_a} is stage {a.stage!r}", path_b)
    if b.class_map.to_dict() != a.class_map.to_dict():
        raise InputError(f"another class map than {path_a}", path_b)
    da, db = a.config.to_dict(), b.config.to_dict()
    for section in ("grid", "model", "dynamic_shift"):
        if da[section] != db[section]:
            keys = sorted(k for k in da[section] if da[section][k] != db[section].get(k))
            raise InputError(
                f"another network than {path_a}: config {section}.{', '.join(keys)} differs",
                path_b,
            )
    for part in ("backbone", "shift"):
        sa, sb = getattr(a, part), getattr(b, part)
        if sa is None:
            continue
        if sa.keys() != sb.keys():
            extra = sorted(set(sa) ^ set(sb))
            raise InputError(
                f"{part} tensors differ from {path_a}'s: {', '.join(extra[:3])}", path_b
            )
        for key, value in sa.items():
            other = sb[key]
            if other.shape != value.shape or other.is_floating_point() != value.is_floating_point():
                raise InputError(
                    f"{part} tensor {key} is {tuple(other.shape)} {other.dtype}, "
                    f"{path_a} has {tuple(value.shape)} {value.dtype}",
                    path_b,
                )
