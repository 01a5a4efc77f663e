"""torch.distributed helpers: start from ``torchrun`` variables, shard samples, reduce metrics.

A process launched by ``torchrun`` has ``WORLD_SIZE``/``RANK``/``LOCAL_RANK`` set; it joins a
process group (``gloo`` on CPU, ``nccl`` on CUDA). A plain ``python`` process is a world of one
and every helper degrades to a no-op.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import torch
import torch.distributed as dist

T = TypeVar("T")


@dataclass(frozen=True)
class DistInfo:
    """Rank, world size and the device of this process."""

    rank: int = 0
    world_size: int = 1
    device: torch.device = torch.device("cpu")

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1


def init_from_env(device: str | None = None) -> DistInfo:
    """Join the process group when launched by ``torchrun`` (``WORLD_SIZE`` > 1).

    Parameters
    ----------
    device : str, optional
        ``"cpu"`` or ``"cuda"``; default: CUDA when available.
    """
    world = int(os.environ.get("WORLD_SIZE", "1"))
    use_cuda = torch.cuda.is_available() if device is None else device.startswith("cuda")
    if world <= 1:
        return DistInfo(device=torch.device("cuda" if use_cuda else "cpu"))
    rank = int(os.environ["RANK"])
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if use_cuda else "gloo")
    if use_cuda:
        torch.cuda.set_device(local)
        dev = torch.device("cuda", local)
    else:
        dev = torch.device("cpu")
    return DistInfo(rank=rank, world_size=world, device=dev)


def shutdown() -> None:
    """Leave the process group if one was joined."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def shard_order(n: int, epoch: int, seed: int, info: DistInfo, shuffle: bool) -> list[int]:
    """Indices of ``n`` samples that this rank visits in ``epoch``.

    The permutation depends only on ``(seed, epoch)``; ranks take interleaved slices, padded by
    wrapping so every rank runs the same number of steps (as ``DistributedSampler``).
    """
    order = np.random.default_rng([seed, epoch]).permutation(n) if shuffle else np.arange(n)
    per_rank = -(-n // info.world_size)
    padded = np.resize(order, per_rank * info.world_size)
    return [int(i) for i in padded[info.rank :: info.world_size]]


def eval_shard(n: int, info: DistInfo) -> list[int]:
    """Indices this rank evaluates: each sample exactly once over all ranks."""
    return list(range(info.rank, n, info.world_size))


def reduce_sum(values: Iterable[T], info: DistInfo) -> T | None:
    """Sum accumulators with ``+`` over local values and then over every rank.

    Works for any picklable type with ``+`` (metric accumulators, numpy arrays, floats); each
    rank receives the same total. Returns None when nothing was accumulated anywhere.
    """
    local = _sum_not_none(list(values))
    if not info.enabled:
        return local
    gathered: list[Any] = [None] * info.world_size
    dist.all_gather_object(gathered, local)
    return _sum_not_none(gathered)


def _sum_not_none(items: list[Any]) -> Any:
    total = None
    for item in items:
        if item is not None:
            total = item if total is None else total + item
    return total


def mean_scalar(value: float, count: int, info: DistInfo) -> float:
    """Average a per-rank mean weighted by its count over every rank."""
    if not info.enabled:
        return value
    t = torch.tensor([value * count, float(count)], dtype=torch.float64)
    dist.all_reduce(t)
    return float(t[0] / t[1]) if t[1] > 0 else 0.0


def barrier(info: DistInfo) -> None:
    """Wait for every rank (no-op for a world of one)."""
    if info.enabled:
        dist.barrier()
