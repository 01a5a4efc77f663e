"""Inference-only shortcuts around the sparse convs: in-place BatchNorm / activations, merged convs.

Without gradients and with eval-mode BatchNorm, the layers of the official network can

- apply LeakyReLU and BatchNorm in place on the conv output (one ``leaky_relu_`` and one
  ``addcmul`` with the per-channel ``scale = gamma / sqrt(var + eps)``, ``shift = beta - mean *
  scale``) instead of two fresh (n_sites, C) arrays through ``native_batch_norm``;
- run the convs that read the same tensor through the same kernel map as one conv with their
  weights side by side (one gather, one wider GEMM), e.g. the first convs of the two branches of
  a Cylinder3D asymmetric residual block, the three gates of the reconstruction block, and the
  semantic head with the first conv of the offset head.

Same sums up to float round-off; taken only where :func:`inference_path` says so (a network
built with ``fast_inference=True``, no gradient, at least
:data:`~panoptic_bench.dsnet.sparse.gemm.MIN_THREADS` torch threads), like the inference conv
paths, so training and the pinned nominal network are untouched.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn.modules.batchnorm import _BatchNorm

from panoptic_bench.dsnet.sparse import functional as F
from panoptic_bench.dsnet.sparse import gemm
from panoptic_bench.dsnet.sparse.modules import SubMConv3d
from panoptic_bench.dsnet.sparse.tensor import SparseTensor


def inference_path(x: SparseTensor, *modules: nn.Module) -> bool:
    """True when ``x``'s layers may take the inference shortcuts.

    ``x``'s cache holds :data:`~panoptic_bench.dsnet.sparse.gemm.FAST_KEY`, no gradient is
    recorded (``torch.no_grad`` / ``inference_mode``), torch runs at least
    :data:`~panoptic_bench.dsnet.sparse.gemm.MIN_THREADS` threads and every module in
    ``modules`` is in eval mode with running statistics in each of its BatchNorms (not so under
    :func:`panoptic_bench.dsnet.inference.scan_norm.scan_statistics`).
    """
    return bool(x.cache.get(gemm.FAST_KEY, False)) and inference_enabled(*modules)


def inference_enabled(*modules: nn.Module) -> bool:
    """:func:`inference_path` without the tensor: no gradient, threads, eval-mode modules."""
    if torch.is_grad_enabled() or torch.get_num_threads() < gemm.MIN_THREADS:
        return False
    if any(m.training for m in modules):
        return False
    return not any(
        isinstance(sub, _BatchNorm) and sub.running_mean is None
        for m in modules
        for sub in m.modules()
    )


def norm_scale_shift(norm: nn.BatchNorm1d) -> tuple[torch.Tensor, torch.Tensor]:
    """Eval-mode BatchNorm as ``x * scale + shift``: two arrays of shape (channels,)."""
    if norm.running_var is None or norm.running_mean is None:
        raise ValueError("BatchNorm without running statistics has no eval-mode affine form")
    scale = torch.rsqrt(norm.running_var + norm.eps)
    if norm.weight is not None:
        scale = scale * norm.weight
    shift = -norm.running_mean * scale
    if norm.bias is not None:
        shift = shift + norm.bias
    return scale, shift


def norms_scale_shift(norms: list[nn.BatchNorm1d]) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`norm_scale_shift` of several norms, concatenated (merged convs)."""
    pairs = [norm_scale_shift(n) for n in norms]
    return torch.cat([p[0] for p in pairs]), torch.cat([p[1] for p in pairs])


def affine_(features: torch.Tensor, scale: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """``features = features * scale + shift`` in place; features (n, C), scale/shift (C,)."""
    return torch.addcmul(shift.to(features.dtype), features, scale.to(features.dtype), out=features)


def act_norm_(
    features: torch.Tensor, act: nn.LeakyReLU, norms: list[nn.BatchNorm1d]
) -> torch.Tensor:
    """LeakyReLU then eval BatchNorm, in place.

    Parameters
    ----------
    features : torch.Tensor
        Array of shape (n_sites, sum of the norms' channels), contiguous, overwritten.
    act : nn.LeakyReLU
    norms : list of nn.BatchNorm1d
        Applied to consecutive column blocks (one norm per merged conv).

    Returns
    -------
    torch.Tensor
        ``features``.
    """
    torch.nn.functional.leaky_relu_(features, act.negative_slope)
    return affine_(features, *norms_scale_shift(norms))


def norm_act_(features: torch.Tensor, norm: nn.BatchNorm1d, act: nn.LeakyReLU) -> torch.Tensor:
    """Eval BatchNorm then LeakyReLU, in place on ``features`` (n_sites, C); returns it."""
    affine_(features, *norm_scale_shift(norm))
    return torch.nn.functional.leaky_relu_(features, act.negative_slope)


def can_merge(convs: list[SubMConv3d]) -> bool:
    """Whether ``convs`` apply the same kernel map (same effective kernel) to their input."""
    first = convs[0]
    return all(
        c.effective_kernel == first.effective_kernel and c.in_channels == first.in_channels
        for c in convs
    )


def merged_conv(x: SparseTensor, convs: list[SubMConv3d]) -> SparseTensor:
    """All ``convs`` applied to ``x`` as one conv: outputs side by side, in ``convs`` order.

    Parameters
    ----------
    x : SparseTensor
        Input with ``in_channels`` features.
    convs : list of SubMConv3d
        Same input width and effective kernel (:func:`can_merge`).

    Returns
    -------
    SparseTensor
        Features of shape (n_sites, sum of the convs' out_channels).
    """
    if not can_merge(convs):
        raise ValueError("convs with different effective kernels or inputs cannot be merged")
    kernel = convs[0].effective_kernel
    n = math.prod(kernel)
    weight = torch.cat([c.weight[:n] for c in convs], dim=2)
    if all(c.bias is None for c in convs):
        bias = None
    else:
        bias = torch.cat(
            [c.weight.new_zeros(c.out_channels) if c.bias is None else c.bias for c in convs]
        )
    return F.submanifold_conv3d(x, weight, kernel, bias)


MLP_BLOCK_ROWS = 4096
"""Rows per block of :func:`folded_mlp`: the whole stack runs on one block while its
intermediate arrays stay in cache (the official point MLP, 124k points at 2 threads: 97 ms in
blocks of 4096 rows against 204 ms layer by layer over all rows; 512-16384 all beat it)."""


def fold_mlp(mlp: nn.Sequential) -> list[tuple[torch.Tensor, torch.Tensor, bool]]:
    """An eval-mode ``Linear`` / ``BatchNorm1d`` / ``ReLU`` stack as ``(weight_t, bias, relu)`` steps.

    Each BatchNorm becomes part of the adjacent Linear (``W diag(s)``, ``W t + b`` for a norm
    before it, ``diag(s) W``, ``s b + t`` for one after it); a norm with no Linear next to it
    becomes a step with the weight ``diag(s)``. A step is ``h @ weight_t + bias``, then ``relu_`` when
    ``relu``.

    Raises
    ------
    TypeError
        For a layer that is none of the three.
    """
    steps: list[list] = []  # [weight_t, bias, relu]
    pending: tuple[torch.Tensor, torch.Tensor] | None = None  # a norm before the next Linear
    open_linear = False  # the last step is a Linear that a norm may still fold into

    def close_pending() -> None:
        nonlocal pending
        if pending is not None:  # a norm with no Linear before it: diag(s) as a weight
            steps.append([torch.diag(pending[0]), pending[1], False])
            pending = None

    for layer in mlp:
        if isinstance(layer, nn.Linear):
            weight = layer.weight
            bias = layer.bias if layer.bias is not None else weight.new_zeros(weight.shape[0])
            if pending is not None:
                scale, shift = pending
                bias = bias + weight @ shift
                weight = weight * scale
                pending = None
            steps.append([weight.t(), bias, False])
            open_linear = True
        elif isinstance(layer, nn.BatchNorm1d):
            scale, shift = norm_scale_shift(layer)
            if open_linear:
                weight_t, bias = steps[-1][0], steps[-1][1]
                steps[-1][0], steps[-1][1] = weight_t * scale, bias * scale + shift
            elif pending is None:
                pending = (scale, shift)
            else:
                pending = (pending[0] * scale, pending[1] * scale + shift)
        elif isinstance(layer, nn.ReLU):
            close_pending()
            if not steps:
                steps.append([None, None, True])  # a ReLU first: no affine step before it
            else:
                steps[-1][2] = True
            open_linear = False
        else:
            raise TypeError(f"cannot fold {type(layer).__name__} into a Linear")
    close_pending()
    return [(w, b, r) for w, b, r in steps]


def folded_mlp(mlp: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """Run an eval-mode ``Linear`` / ``BatchNorm1d`` / ``ReLU`` stack with the norms folded.

    The stack (:func:`fold_mlp`) runs as one ``addmm`` per Linear and an in-place ``relu_``, on
    blocks of :data:`MLP_BLOCK_ROWS` rows: no (n, C) array per norm or per hidden layer.

    Parameters
    ----------
    mlp : nn.Sequential
        Of ``nn.Linear``, ``nn.BatchNorm1d`` (eval mode, running statistics) and ``nn.ReLU``;
        a norm folds into the Linear before it, else into the next one.
    x : torch.Tensor
        Array of shape (n, in_features).

    Returns
    -------
    torch.Tensor
        Array of shape (n, out_features): ``mlp(x)`` up to float round-off.
    """
    steps = fold_mlp(mlp)
    if not steps:
        return x
    width = next((w.shape[1] for w, _, _ in reversed(steps) if w is not None), x.shape[1])
    out = x.new_empty((x.shape[0], width))
    for a in range(0, x.shape[0], MLP_BLOCK_ROWS):
        h = x[a : a + MLP_BLOCK_ROWS]
        for weight_t, bias, relu in steps:
            h = torch.relu(h) if weight_t is None else torch.addmm(bias, h, weight_t)
            if relu and weight_t is not None:
                torch.relu_(h)
        out[a : a + MLP_BLOCK_ROWS] = h
    return out
