"""How far one dataset's activation statistics sit from another's, as one network sees them.

A network with held (running) BatchNorm statistics normalises every scan with the same mean and
variance. :func:`held_unit_statistics` records, for every BatchNorm of a backbone and every
scan, the per-channel mean and standard deviation of the BatchNorm's input in units of those
held statistics (``(x - running_mean) / sqrt(running_var + eps)``): 0 and 1 for a scan that
looks like the statistics' average. :func:`layer_gaps` compares two such records, e.g. the
synthetic training world (reference) and the real scans (other): how far the other dataset's
channel means sit from the reference's (``offset``), against the reference's own scan-to-scan
spread of them (``spread``), and how much the channel spreads differ (``log_std``). It is the
network-level counterpart of ``synth stats --real`` (issue 13, session 39; used to choose the
spread of ``optim.bn_noise``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from panoptic_bench.dsnet.data.datasets import LidarSample
from panoptic_bench.dsnet.model.forward import backbone_forward

__all__ = [
    "GAP_FIELDS",
    "ScanStatistics",
    "evenly_spaced",
    "held_unit_statistics",
    "layer_gaps",
    "write_gap_files",
]

#: Columns of :func:`layer_gaps` rows (after ``layer``), in order.
GAP_FIELDS = ("channels", "offset", "spread", "ratio", "log_std")


@dataclass
class ScanStatistics:
    """Per-scan channel statistics of every BatchNorm input, in held units.

    ``means[name]`` and ``stds[name]``: (n_scans, channels) float64 arrays, in the order the
    backbone's modules are named (``named_modules``).
    """

    means: dict[str, np.ndarray]
    stds: dict[str, np.ndarray]


def held_unit_statistics(
    backbone: nn.Module, samples: Iterable[LidarSample], grid, device: torch.device | str = "cpu"
) -> ScanStatistics:
    """Run ``backbone`` (eval mode, no gradients) on each sample and record every BatchNorm's
    input statistics in held units (see the module docstring).

    Parameters
    ----------
    backbone : nn.Module
        Left in eval mode; its parameters and buffers are not changed.
    samples : iterable of LidarSample
        One forward pass each (a batch of one scan).
    grid : CylinderGrid
        The checkpoint's voxel grid.
    """
    norms = {
        name: m
        for name, m in backbone.named_modules()
        if isinstance(m, nn.modules.batchnorm._BatchNorm)
    }
    rows: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {name: [] for name in norms}

    def recorder(name: str):
        def hook(bn: nn.Module, args: tuple) -> None:
            x = args[0].detach().double()
            z = (x - bn.running_mean.double()) / torch.sqrt(bn.running_var.double() + bn.eps)
            std = z.std(0) if len(z) > 1 else torch.zeros_like(z[0])
            rows[name].append((z.mean(0).cpu().numpy(), std.cpu().numpy()))

        return hook

    handles = [m.register_forward_pre_hook(recorder(n)) for n, m in norms.items()]
    backbone.eval()
    try:
        with torch.no_grad():
            for sample in samples:
                backbone_forward(backbone, [sample], grid, torch.device(device))
    finally:
        for h in handles:
            h.remove()
    used = [n for n in norms if rows[n]]
    return ScanStatistics(
        {n: np.stack([m for m, _ in rows[n]]) for n in used},
        {n: np.stack([s for _, s in rows[n]]) for n in used},
    )


def layer_gaps(reference: ScanStatistics, other: ScanStatistics) -> list[dict]:
    """Per BatchNorm, how far ``other``'s channel statistics sit from ``reference``'s.

    Every value is the median over the layer's channels of:

    - ``offset``: |mean over other's scans of the channel mean - the same over reference's|;
    - ``spread``: standard deviation over reference's scans of the channel mean;
    - ``ratio``: offset / spread of the channel (a channel with spread 0 is left out);
    - ``log_std``: |log(mean channel std of other / that of reference)|.

    Returns one dict per layer both hold (keys ``layer`` and :data:`GAP_FIELDS`), in
    ``reference``'s order, then a last row ``layer = "median"`` with each column's median over
    the layers.
    """
    out = []
    for name, ref_mean in reference.means.items():
        if name not in other.means:
            continue
        oth_mean = other.means[name]
        offset = np.abs(oth_mean.mean(0) - ref_mean.mean(0))
        spread = ref_mean.std(0)
        keep = spread > 0
        ref_std = reference.stds[name].mean(0)
        oth_std = other.stds[name].mean(0)
        pos = (ref_std > 0) & (oth_std > 0)
        out.append(
            {
                "layer": name,
                "channels": int(ref_mean.shape[1]),
                "offset": float(np.median(offset)),
                "spread": float(np.median(spread)),
                "ratio": float(np.median(offset[keep] / spread[keep])) if keep.any() else np.nan,
                "log_std": float(np.median(np.abs(np.log(oth_std[pos] / ref_std[pos]))))
                if pos.any()
                else np.nan,
            }
        )
    if out:
        summary = {"layer": "median", "channels": int(np.median([r["channels"] for r in out]))}
        for key in GAP_FIELDS[1:]:
            summary[key] = float(np.nanmedian([r[key] for r in out]))
        out.append(summary)
    return out


def evenly_spaced(n: int, count: int) -> list[int]:
    """``count`` indices spread evenly over ``range(n)`` (all of them when ``count`` >= n)."""
    if count >= n:
        return list(range(n))
    return sorted({int(round(i)) for i in np.linspace(0, n - 1, count)})


def write_gap_files(rows: list[dict], out_dir, title: str) -> list:
    """Write ``gap.csv`` (one row per layer, then the medians) and ``gap.png`` (offset and
    spread per layer) under ``out_dir``, atomically; returns their paths."""
    import csv
    import io
    from pathlib import Path

    from panoptic_bench.io import write_text
    from panoptic_bench.reports.style import figure

    out = Path(out_dir)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=("layer", *GAP_FIELDS), lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in r.items()})
    write_text(out / "gap.csv", buf.getvalue())
    layers = [r for r in rows if r["layer"] != "median"]
    x = np.arange(len(layers))
    with figure(out / "gap.png", size=(max(6.0, 0.18 * len(layers) + 2), 3.6)) as (_, axes):
        ax = axes[0, 0]
        ax.bar(x - 0.2, [r["offset"] for r in layers], 0.4, label="offset of the channel means")
        ax.bar(x + 0.2, [r["spread"] for r in layers], 0.4, label="reference scan-to-scan spread")
        ax.set_xticks(x, [r["layer"] for r in layers], rotation=90, fontsize=5)
        ax.set_ylabel("held std (median over channels)")
        ax.set_title(title, fontsize=8)
        ax.legend(fontsize=7)
    return [out / "gap.csv", out / "gap.png"]
