"""The measured ablations of issue 7 on a frozen backbone: Table 4, Table 5, Figs. 4a-c and 5-7.

:func:`run_ablation` (CLI ``panoptic-bench ablate``):

1. runs the frozen backbone of a stage-2 checkpoint once over the training and validation scans
   (:mod:`.cache`);
2. trains one dynamic shifting module per variant on the cache (Adam, the stage-``ds`` loss
   :func:`~panoptic_bench.dsnet.model.ds_head.shift_training_loss`, fixed seed): the paper's six
   bandwidth sets (Table 4, read from :func:`panoptic_bench.reports.paper.paper_table`), 1-5
   iterations (Table 5) and direct regression with a Gaussian kernel (Fig. 4c);
3. scores every variant on the validation cache (DS clustering: final mean shift, nearest seed,
   consensus fusion; :mod:`.scoring`), plus Backbone, Backbone with Fusion and BFS /
   DBSCAN / HDBSCAN on the very same regressed centres (Figs. 4a/4b), each into
   ``OUT/runs/<name>/`` (``scores.json``, ``run.json``); the default variant also gets the
   per-seed diagnostics of Figs. 5-7 (``analysis.json``, ``shift_iterations.npz``);
4. builds the report (``OUT/report``) from ``OUT/runs/*``.

Because the backbone is frozen in stage ``ds``, training on the cache optimises the same loss
on the same inputs as ``panoptic-bench train --stage ds`` (without its augmentation), in
minutes instead of hours.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from panoptic_bench.dsnet.ablation.cache import TrainScan, build_cache, scan_refs
from panoptic_bench.dsnet.config import ShiftKernel
from panoptic_bench.dsnet.model.dynamic_shift import DynamicShift

__all__ = [
    "AblationSummary",
    "Variant",
    "paper_bandwidth_sets",
    "run_ablation",
    "train_variant",
    "variants",
]

DEFAULT_BANDWIDTHS = (0.2, 1.7, 3.2)
DEFAULT_ITERATIONS = 4
TABLE5_ITERATIONS = (1, 2, 3, 4, 5)


@dataclass(frozen=True)
class Variant:
    """One dynamic shifting module to train and score.

    ``table4`` / ``table5``: whether its run carries ``bandwidths`` / ``iterations`` in
    ``run.json`` (i.e. is a row of Table 4 / Table 5); ``ablation``: Fig. 4 bar tags.
    """

    name: str
    method: str
    bandwidths: tuple[float, ...]
    iterations: int
    kernel: ShiftKernel = ShiftKernel.FLAT
    table4: bool = False
    table5: bool = False
    ablation: dict[str, str] = field(default_factory=dict)

    @property
    def is_default(self) -> bool:
        """The paper's DS-Net: 0.2/1.7/3.2 m, 4 iterations, weighted flat candidates."""
        return (
            self.bandwidths == DEFAULT_BANDWIDTHS
            and self.iterations == DEFAULT_ITERATIONS
            and self.kernel is ShiftKernel.FLAT
        )


def paper_bandwidth_sets() -> list[tuple[float, ...]]:
    """The six bandwidth-candidate sets of the paper's Table 4 (from the packaged table data)."""
    from panoptic_bench.reports.paper import paper_table

    return [tuple(float(v) for v in str(row).split(",")) for row in paper_table(4).index]


def _bw_slug(bandwidths: Sequence[float]) -> str:
    return "-".join(f"{b:.1f}" if round(b, 1) == b else f"{b:g}" for b in bandwidths)


def variants(quick: bool = False) -> list[Variant]:
    """Every DS variant: Table 4 sets, Table 5 iterations, direct regression (Fig. 4c).

    The default (0.2, 1.7, 3.2 m, 4 iterations) is trained once and is a row of both tables.
    ``quick`` keeps the default, one other bandwidth set, 1 iteration and direct regression.
    """
    from panoptic_bench.reports.tables import format_bandwidths

    sets = paper_bandwidth_sets()
    iters = TABLE5_ITERATIONS
    if quick:
        sets = [s for s in sets if s == DEFAULT_BANDWIDTHS] + [sets[0]]
        iters = (1, DEFAULT_ITERATIONS)
    out = [
        Variant(
            "dsnet",
            "DS-Net",
            DEFAULT_BANDWIDTHS,
            DEFAULT_ITERATIONS,
            table4=True,
            table5=True,
            ablation={
                "framework": "+ DS",
                "clustering": "DS",
                "bandwidth_learning": "weighted candidates",
            },
        )
    ]
    for bws in sets:
        if bws != DEFAULT_BANDWIDTHS:
            label = f"DS-Net (bandwidths {format_bandwidths(bws)})"
            out.append(Variant(f"dsnet-bw-{_bw_slug(bws)}", label, bws, 4, table4=True))
    for its in iters:
        if its != DEFAULT_ITERATIONS:
            label = f"DS-Net ({its} iteration{'s' if its > 1 else ''})"
            out.append(Variant(f"dsnet-iter-{its}", label, DEFAULT_BANDWIDTHS, its, table5=True))
    out.append(
        Variant(
            "dsnet-direct-regression",
            "DS-Net (direct regression, Gaussian kernel)",
            DEFAULT_BANDWIDTHS,
            DEFAULT_ITERATIONS,
            kernel=ShiftKernel.GAUSSIAN,
            ablation={"bandwidth_learning": "direct regression"},
        )
    )
    return out


def train_variant(
    variant: Variant,
    cache: Sequence[TrainScan],
    *,
    steps: int,
    lr: float,
    hidden: int = 64,
    seed: int = 0,
    progress: bool = True,
) -> tuple[DynamicShift, list[float]]:
    """Train one dynamic shifting module on cached seeds (Adam, paper loss eq. 4-5).

    Parameters
    ----------
    variant : Variant
    cache : sequence of TrainScan
        One scan per step, in a seeded random order (a new permutation every pass).
    steps : int
        Optimiser steps (0 = the randomly initialised module).
    lr : float
        Adam learning rate.
    seed : int
        Seeds the module's initialisation and the scan order.

    Returns
    -------
    (DynamicShift, list of float)
        The trained module (eval mode) and the loss of every step.
    """
    from tqdm import tqdm

    from panoptic_bench.dsnet.model.ds_head import shift_training_loss

    if not cache:
        raise ValueError("no cached training scan with ground-truth things points")
    torch.manual_seed(seed)
    feat_dim = cache[0].features.shape[1]
    module = DynamicShift(
        feat_dim, variant.bandwidths, variant.iterations, hidden=hidden, kernel=variant.kernel
    )
    opt = torch.optim.Adam(module.parameters(), lr=lr)
    rng = np.random.default_rng(seed)
    order: list[int] = []
    losses = []
    module.train()
    bar = tqdm(range(steps), desc=f"train {variant.name}", leave=False, disable=not progress)
    for _ in bar:
        if not order:
            order = rng.permutation(len(cache)).tolist()
        scan = cache[order.pop()]
        opt.zero_grad(set_to_none=True)
        loss = shift_training_loss(
            module,
            torch.from_numpy(scan.centers),
            torch.from_numpy(scan.features),
            torch.from_numpy(scan.gt_centers),
            max_seeds=len(scan.centers),
            iteration_weights=[1.0] * variant.iterations,
        )
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        bar.set_postfix(loss=f"{losses[-1]:.3f}")
    return module.eval(), losses


@dataclass
class AblationSummary:
    """What :func:`run_ablation` did: run directories, report index, timings (s)."""

    out: Path
    runs: list[Path]
    report: Path | None
    seconds: dict[str, float]
    rows: list[dict] = field(default_factory=list)


def run_ablation(
    checkpoint: str | Path,
    data_root: str | Path,
    out: str | Path,
    *,
    train_sequences: Sequence[str] | None = None,
    val_sequences: Sequence[str] | None = None,
    steps: int = 300,
    max_train_scans: int = 0,
    max_val_scans: int = 0,
    quick: bool = False,
    lr: float | None = None,
    seed: int = 0,
    data_label: str | None = None,
    report: bool = True,
    command: str | None = None,
    progress: bool = True,
) -> AblationSummary:
    """Every measured ablation of issue 7 on the frozen backbone of ``checkpoint``.

    Parameters
    ----------
    checkpoint : path
        Stage-2 (offset) checkpoint (a DS checkpoint works too: only its backbone is used).
    data_root : path
        Labelled SemanticKITTI-format root.
    out : path
        Output directory (created): ``runs/<name>/`` per variant / baseline, ``report/``,
        ``timing.json`` (seconds per phase).
    train_sequences, val_sequences : sequence of str, optional
        Sequences the DS variants train on / that are scored (default: the checkpoint config's
        ``data.train_sequences`` / ``data.val_sequences``, i.e. the backbone's own split).
    steps : int
        Training steps of every DS variant (one cached scan per step).
    max_train_scans, max_val_scans : int
        Evenly spaced subsets of the scans (0 = all).
    quick : bool
        Fewer variants (see :func:`variants`).
    lr : float, optional
        Adam learning rate (default: the checkpoint config's ``optim.lr``).
    data_label : str, optional
        How ``run.json`` ``data`` names the data root (default: its path).
    command : str, optional
        Shell command recorded in every ``run.json`` and in the report.

    Returns
    -------
    AblationSummary
    """
    from panoptic_bench.dsnet.ablation.scoring import EvalContext, score_baselines, score_variant
    from panoptic_bench.dsnet.checkpoint import load_checkpoint
    from panoptic_bench.errors import InputError
    from panoptic_bench.io import ensure_output_dir, write_json

    t_start = time.perf_counter()
    ckpt = load_checkpoint(checkpoint)
    if ckpt.class_map.dataset != "semantickitti":
        raise InputError("ablate needs a SemanticKITTI-format checkpoint and data", checkpoint)
    train_sequences = list(train_sequences or ckpt.config.data.train_sequences)
    val_sequences = list(val_sequences or ckpt.config.data.val_sequences)
    train_refs = scan_refs(data_root, train_sequences, max_train_scans)
    val_refs = scan_refs(data_root, val_sequences, max_val_scans)
    for what, refs, seqs in (("training", train_refs, train_sequences), ("validation", val_refs, val_sequences)):  # fmt: skip
        if not refs:
            raise InputError(f"no {what} scans in sequences {','.join(seqs)}", data_root)
        unlabelled = [r.label for r in refs if not r.label.is_file()]
        if unlabelled:
            raise InputError(
                f"{what} scan without labels (ablate needs labelled scans)", unlabelled[0]
            )
    out = ensure_output_dir(out, overwrite=True, inputs=(data_root,))
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    train_cache, val_cache = build_cache(ckpt, train_refs, val_refs, progress=progress)
    seconds["cache"] = time.perf_counter() - t0
    cfg = ckpt.config
    lr = cfg.optim.lr if lr is None else lr
    n_seeds = int(np.mean([len(s.centers) for s in train_cache])) if train_cache else 0
    ctx = EvalContext(
        ckpt=ckpt,
        scans=val_cache,
        runs_dir=out / "runs",
        data=f"{data_label or data_root} seq {','.join(val_sequences)} ({len(val_cache)} scans)",
        training=(
            f"DS trained on the frozen-backbone cache of {len(train_cache)} scans of seq "
            f"{','.join(train_sequences)} (mean {n_seeds} FPS seeds/scan): {steps} Adam steps, "
            f"lr {lr:g}, seed {seed}, one scan per step, no augmentation"
        ),
        checkpoint=f"{checkpoint} (stage {ckpt.stage}, epoch {ckpt.epoch})",
        command=command,
        progress=progress,
    )
    runs, rows = [], []
    for variant in variants(quick):
        t0 = time.perf_counter()
        module, losses = train_variant(
            variant, train_cache, steps=steps, lr=lr, seed=seed, progress=progress
        )
        seconds[f"train {variant.name}"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        path, row = score_variant(ctx, variant, module, losses)
        seconds[f"score {variant.name}"] = time.perf_counter() - t0
        runs.append(path)
        rows.append(row)
    t0 = time.perf_counter()
    for path, row in score_baselines(ctx):
        runs.append(path)
        rows.append(row)
    seconds["baselines"] = time.perf_counter() - t0
    index = None
    if report:
        from panoptic_bench.reports.index import build_report

        t0 = time.perf_counter()
        index = build_report(runs, out / "report", command=command)
        seconds["report"] = time.perf_counter() - t0
    seconds["total"] = time.perf_counter() - t_start
    write_json(out / "timing.json", {k: round(v, 2) for k, v in seconds.items()})
    return AblationSummary(out, runs, index, seconds, rows)
