"""Backbone losses: weighted cross-entropy + Lovász-softmax (semantic), L1 offsets (instance).

Ground-truth instance centres are the centres of the axis-aligned tight boxes of each
instance's points (paper appendix §4), not their mass centres.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import torch
import torch.nn.functional as F


def label_counts(labels: Iterable[np.ndarray | torch.Tensor], num_classes: int) -> np.ndarray:
    """Point count per class over label arrays, shape (num_classes,), int64.

    Labels outside ``[0, num_classes)`` are an error (remap them first).
    """
    counts = np.zeros(num_classes, dtype=np.int64)
    for lab in labels:
        lab = np.asarray(lab.cpu() if isinstance(lab, torch.Tensor) else lab).ravel()
        if lab.size and (lab.min() < 0 or lab.max() >= num_classes):
            raise ValueError(f"labels must lie in [0, {num_classes}); remap them first")
        counts += np.bincount(lab, minlength=num_classes)
    return counts


def class_weights(
    counts: np.ndarray | torch.Tensor, power: float = 0.5, ignore_index: int | None = 0
) -> torch.Tensor:
    """Cross-entropy class weights from training-set frequencies.

    ``w_c = (f_c + 1e-3) ** -power`` with ``f_c`` the class frequency (ignored class excluded),
    normalised so that the classes present have mean weight 1; the ignored class and absent
    classes get weight 0.

    Parameters
    ----------
    counts : array of shape (num_classes,)
        Points per class (:func:`label_counts`).
    power : float
        0 gives uniform weights, 1 inverse frequency; 0.5 (default) inverse square root.
    ignore_index : int or None

    Returns
    -------
    torch.Tensor
        Array of shape (num_classes,), float32.
    """
    c = torch.as_tensor(np.asarray(counts, dtype=np.float64))
    if ignore_index is not None:
        c[ignore_index] = 0
    total = c.sum()
    if total <= 0:
        raise ValueError("no labelled points to compute class weights from")
    w = (c / total + 1e-3) ** (-power)
    w[c == 0] = 0
    return (w / w[c > 0].mean()).float()


def lovasz_grad(gt_sorted: torch.Tensor) -> torch.Tensor:
    """Gradient of the Lovász extension of the Jaccard loss w.r.t. sorted errors, shape (n,)."""
    gts = gt_sorted.sum()
    intersection = gts - gt_sorted.cumsum(0)
    union = gts + (1 - gt_sorted).cumsum(0)
    jaccard = 1.0 - intersection / union
    if gt_sorted.numel() > 1:
        jaccard[1:] = jaccard[1:] - jaccard[:-1]
    return jaccard


def lovasz_softmax(
    probs: torch.Tensor,
    labels: torch.Tensor,
    ignore_index: int | None = 0,
    only_present: bool = True,
) -> torch.Tensor:
    """Lovász-softmax loss (Berman et al. 2018): mean over classes of the Lovász extension of
    the Jaccard loss on errors ``|[label == c] - p_c|``.

    Parameters
    ----------
    probs : torch.Tensor
        Array of shape (n, C), class probabilities (softmax output).
    labels : torch.Tensor
        Array of shape (n,), int64.
    ignore_index : int or None
        Points with this label are dropped; the class itself is never scored.
    only_present : bool
        Average only over classes present in ``labels`` (reference default).

    Returns
    -------
    torch.Tensor
        Scalar; 0 when no point is left.
    """
    if ignore_index is not None:
        keep = labels != ignore_index
        probs, labels = probs[keep], labels[keep]
    if labels.numel() == 0:
        return probs.sum() * 0.0
    losses = []
    for c in range(probs.shape[1]):
        if c == ignore_index:
            continue
        fg = (labels == c).to(probs.dtype)
        if only_present and fg.sum() == 0:
            continue
        errors = (fg - probs[:, c]).abs()
        errors_sorted, perm = torch.sort(errors, descending=True)
        losses.append(torch.dot(errors_sorted, lovasz_grad(fg[perm])))
    if not losses:
        return probs.sum() * 0.0
    return torch.stack(losses).mean()


def semantic_loss(
    logits: torch.Tensor,
    labels: torch.Tensor,
    weight: torch.Tensor | None = None,
    ignore_index: int = 0,
    ce_weight: float = 1.0,
    lovasz_weight: float = 1.0,
    soft: torch.Tensor | None = None,
    distill: float = 0.0,
) -> torch.Tensor:
    """``ce_weight * weighted CE + lovasz_weight * Lovász-softmax`` on (n, C) logits.

    With ``soft`` (n, C) teacher probabilities and ``distill`` = a > 0 the CE target of every
    labelled point is ``(1 - a) * one_hot(label) + a * soft`` (:func:`soft_cross_entropy`);
    Lovász-softmax keeps the labels.
    """
    valid = labels != ignore_index
    if not bool(valid.any()):
        return logits.sum() * 0.0
    w = None if weight is None else weight.to(device=logits.device, dtype=logits.dtype)
    if soft is not None and distill > 0:
        hard = F.one_hot(labels[valid], logits.shape[1]).to(logits.dtype)
        target = (1.0 - distill) * hard + distill * soft[valid].to(logits.dtype)
        ce = soft_cross_entropy(logits[valid], target, w)
    else:
        ce = F.cross_entropy(logits, labels, weight=w, ignore_index=ignore_index)
    lov = lovasz_softmax(F.softmax(logits, dim=1), labels, ignore_index=ignore_index)
    return ce_weight * ce + lovasz_weight * lov


def soft_cross_entropy(
    logits: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None
) -> torch.Tensor:
    """Class-weighted cross-entropy against probability rows.

    ``sum_i sum_c w_c t_ic (-log softmax(z_i)_c) / sum_i sum_c w_c t_ic``: with one-hot rows it
    is exactly :func:`torch.nn.functional.cross_entropy`'s weighted mean.

    Parameters
    ----------
    logits, target : Tensor of shape (n, C)
        Rows of ``target`` are probabilities.
    weight : Tensor of shape (C,), optional
    """
    w = torch.ones(logits.shape[1], dtype=logits.dtype, device=logits.device)
    w = w if weight is None else weight
    wt = target * w[None, :]
    return -(wt * F.log_softmax(logits, dim=1)).sum() / wt.sum().clamp_min(1e-12)


def instance_centers(
    xyz: torch.Tensor, instance_ids: torch.Tensor, batch_index: torch.Tensor | None = None
) -> torch.Tensor:
    """Centre of the axis-aligned tight box of each point's instance.

    Parameters
    ----------
    xyz : torch.Tensor
        Array of shape (n, 3), float.
    instance_ids : torch.Tensor
        Array of shape (n,), integer; points with equal ids (and equal ``batch_index``) form one
        instance. Stuff points get a centre too; mask them out of the loss.
    batch_index : torch.Tensor, optional
        Array of shape (n,), integer scan index, so ids may repeat across scans.

    Returns
    -------
    torch.Tensor
        Array of shape (n, 3), same dtype as ``xyz``: ``(min + max) / 2`` of the instance.
    """
    ids = instance_ids.long()
    if batch_index is not None:
        ids = torch.stack([batch_index.long(), ids], dim=1)
        _, group = torch.unique(ids, dim=0, return_inverse=True)
    else:
        _, group = torch.unique(ids, return_inverse=True)
    n_groups = int(group.max().item()) + 1 if group.numel() else 0
    index = group[:, None].expand(-1, 3)
    lo = xyz.new_zeros((n_groups, 3)).scatter_reduce(0, index, xyz, "amin", include_self=False)
    hi = xyz.new_zeros((n_groups, 3)).scatter_reduce(0, index, xyz, "amax", include_self=False)
    return ((lo + hi) / 2)[group]


def offset_loss(
    offsets: torch.Tensor, xyz: torch.Tensor, centers: torch.Tensor, mask: torch.Tensor
) -> torch.Tensor:
    """Paper eq. (1): mean over masked (things) points of ``|| O - (C_gt - P) ||_1``.

    Parameters
    ----------
    offsets, xyz, centers : torch.Tensor
        Arrays of shape (n, 3), float.
    mask : torch.Tensor
        Array of shape (n,), bool: things points.

    Returns
    -------
    torch.Tensor
        Scalar; 0 (with a gradient path) when no point is masked.
    """
    m = mask.to(offsets.dtype)
    dist = (offsets - (centers - xyz)).abs().sum(dim=1)
    return (dist * m).sum() / (m.sum() + 1e-6)
