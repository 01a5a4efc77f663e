"""DS-Net training: stage 1 (semantic), stage 2 (offsets), stage ``ds`` (dynamic shifting).

Layout of a run directory::

    RUN_DIR/run.json               method / dataset / data / notes, for the report builder
    RUN_DIR/platform.json          the machine of every call (training/platform.py)
    RUN_DIR/config.yaml            the typed config actually used
    RUN_DIR/metrics.csv            one row per stage and epoch (train loss, val mIoU / PQ ...)
    RUN_DIR/checkpoints/{semantic,offset,ds}.pt

Each stage starts from the previous stage's checkpoint in the same run directory (or ``init``),
optimises with Adam and saves a checkpoint after every epoch. ``resume=True`` continues the
stage from its checkpoint; on CPU with a fixed seed, on one kind of machine with one thread
count (``platform.json``), the result is bit-for-bit the same as an uninterrupted run (sample
order and augmentation derive from ``(seed, epoch, index)``, and the optimizer and torch RNG
state are restored). Launched by ``torchrun``, every process trains on
its shard of the samples (DDP) and validation accumulators are summed over the processes.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from panoptic_bench.dsnet import distributed as ddp
from panoptic_bench.dsnet.checkpoint import (
    STAGES,
    Checkpoint,
    build_backbone,
    build_grid,
    build_shift,
    load_checkpoint,
    save_checkpoint,
    widen_point_inputs,
)
from panoptic_bench.dsnet.config import DSNetConfig, HeldStatistics, save_config
from panoptic_bench.dsnet.data.bank import open_bank
from panoptic_bench.dsnet.data.datasets import ClassMap, LidarDataset, open_dataset
from panoptic_bench.dsnet.data.training_set import TrainingSet
from panoptic_bench.dsnet.training.averaging import (
    StepAverage,
    finish_stage_average,
    stage_average,
)
from panoptic_bench.dsnet.training.batchnorm import (
    hold_batchnorm_statistics,
    measure_held_statistics,
    statistics_noise,
)
from panoptic_bench.dsnet.training.metrics_log import write_metrics_csv
from panoptic_bench.dsnet.training.platform import record_platform
from panoptic_bench.dsnet.training.resume import check_resumable, checkpoint_path, start_checkpoint
from panoptic_bench.dsnet.training.steps import (
    class_weights_for,
    step_loss,
)
from panoptic_bench.errors import InputError

__all__ = ["TrainContext", "train", "run_stage", "train_one_epoch"]


@dataclass
class TrainContext:
    """Everything a stage needs, built once by :func:`train`."""

    cfg: DSNetConfig
    run_dir: Path
    train_set: TrainingSet
    val_set: LidarDataset
    class_map: ClassMap
    class_weights: list[float]
    info: ddp.DistInfo
    grid: Any = None
    progress: bool = True


def seed_everything(seed: int) -> None:
    """Seed torch, numpy and Python's ``random``."""
    import random

    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def train(
    cfg: DSNetConfig,
    data_root: str | Path,
    run_dir: str | Path,
    *,
    stage: str = "all",
    resume: bool = False,
    epochs: int | None = None,
    init: str | Path | None = None,
    device: str | None = None,
    progress: bool = True,
    notes: str = "",
) -> dict[str, Path]:
    """Train one stage or all of them (``semantic`` -> ``offset`` -> ``ds``).

    Parameters
    ----------
    cfg : DSNetConfig
    data_root : path
        SemanticKITTI-format or nuScenes-format root (``cfg.data.format``).
    run_dir : path
        Output directory (created).
    stage : {"semantic", "offset", "ds", "all"}
    resume : bool
        Continue each stage from its checkpoint in ``run_dir`` when present.
    epochs : int, optional
        Total epochs of each stage run (overrides ``cfg.optim.epochs_<stage>``).
    init : path, optional
        Checkpoint to start the first stage from (instead of the previous stage in ``run_dir``).
    device : str, optional
        ``cpu`` / ``cuda``; default CUDA when available.

    Returns
    -------
    dict of str to Path
        The checkpoint of each stage run.
    """
    stages = list(STAGES) if stage == "all" else [stage]
    if any(s not in STAGES for s in stages):
        raise InputError(f"unknown stage {stage!r}; choose semantic, offset, ds or all")
    info = ddp.init_from_env(device)
    try:
        ctx = _make_context(cfg, Path(data_root), Path(run_dir), info, progress)
        if info.is_main:
            _write_run_files(ctx, data_root, notes)
            note = record_platform(ctx.run_dir, info.device)
            if note:
                print(f"note: {note}", file=sys.stderr)
        out = {}
        for i, st in enumerate(stages):
            out[st] = run_stage(
                st, ctx, resume=resume, epochs=epochs, init=init if i == 0 else None
            )
        return out
    finally:
        ddp.shutdown()


def _make_context(
    cfg: DSNetConfig, data_root: Path, run_dir: Path, info: ddp.DistInfo, progress: bool
) -> TrainContext:
    train_ds = open_dataset(data_root, cfg.data, "train")
    val_ds = open_dataset(data_root, cfg.data, "val")
    cmap = train_ds.class_map
    labels = [train_ds.load(i).sem for i in range(len(train_ds))]
    weights = class_weights_for(labels, cmap, cfg.loss.class_weight_power)
    run_dir.mkdir(parents=True, exist_ok=True)
    return TrainContext(
        cfg=cfg,
        run_dir=run_dir,
        train_set=TrainingSet(
            train_ds,
            cfg.augment,
            seed=cfg.optim.seed,
            bank=open_bank(cfg.augment, train_ds, progress and info.is_main),
            soft_root=_distill_root(cfg),
        ),
        val_set=val_ds,
        class_map=cmap,
        class_weights=weights,
        info=info,
        grid=build_grid(cfg),
        progress=progress and info.is_main,
    )


def _distill_root(cfg: DSNetConfig) -> Path | None:
    """The teacher-probability root of ``loss.distill`` (None when distillation is off)."""
    if cfg.loss.distill <= 0:
        return None
    root = Path(cfg.loss.distill_probs)
    if not (root / "sequences").is_dir() and not (root / "probs").is_dir():
        raise InputError(
            "loss.distill_probs: no sequences/ or probs/ here; write it with "
            "`panoptic-bench infer --save-probs` on the training root",
            root,
        )
    return root


def _write_run_files(ctx: TrainContext, data_root: str | Path, notes: str) -> None:
    from panoptic_bench.reports.inputs import write_run_meta

    save_config(ctx.cfg, ctx.run_dir / "config.yaml")
    default = f"{len(ctx.train_set)} train / {len(ctx.val_set)} val samples"
    meta = {
        "method": "DS-Net (training run)",
        "dataset": ctx.class_map.dataset,
        "data": str(data_root),
        "notes": notes or default,
    }
    write_run_meta(ctx.run_dir, meta)


def _build_networks(
    ctx: TrainContext, stage: str, start: Checkpoint | None
) -> tuple[nn.Module, nn.Module | None]:
    seed_everything(ctx.cfg.optim.seed)
    backbone = build_backbone(ctx.cfg, ctx.class_map.num_classes)
    if start is not None:  # a start without the shape inputs gets them with zero weights
        backbone.load_state_dict(widen_point_inputs(start.backbone, backbone))
    shift = None
    if stage == "ds":
        shift = build_shift(ctx.cfg, ctx.cfg.model.init_size)
        if start is not None and start.shift is not None:
            shift.load_state_dict(start.shift)
    dev = ctx.info.device
    return backbone.to(dev), None if shift is None else shift.to(dev)


def _trainable(stage: str, backbone: nn.Module, shift: nn.Module | None, cfg: DSNetConfig):
    if stage != "ds":
        return list(backbone.parameters())
    params = list(shift.parameters())  # type: ignore[union-attr]
    if not cfg.dynamic_shift.freeze_backbone:
        params += list(backbone.parameters())
    return params


def run_stage(
    stage: str,
    ctx: TrainContext,
    *,
    resume: bool = False,
    epochs: int | None = None,
    init: str | Path | None = None,
) -> Path:
    """Train one stage to its epoch count; returns the path of its checkpoint."""
    path = checkpoint_path(ctx.run_dir, stage)
    own = load_checkpoint(path) if resume and path.is_file() else None
    if own is not None:
        check_resumable(own.config, ctx.cfg, path)
    start = own or start_checkpoint(ctx.run_dir, stage, init)
    measure = (
        ctx.cfg.optim.freeze_bn
        and ctx.cfg.optim.freeze_bn_from is HeldStatistics.TRAIN
        and stage != "ds"
        and own is None
    )
    if start is None and ctx.cfg.optim.freeze_bn and stage != "ds" and not measure:
        raise InputError(
            f"optim.freeze_bn holds the BatchNorm statistics the {stage} stage starts with, and a "
            "fresh network has none: give --init CHECKPOINT, train the previous stage first or "
            "measure them (optim.freeze_bn_from: train)"
        )
    backbone, shift = _build_networks(ctx, stage, start)
    measured = measure_held_statistics(backbone, ctx) if measure else None
    params = _trainable(stage, backbone, shift, ctx.cfg)
    optimizer = torch.optim.Adam(
        params, lr=ctx.cfg.optim.lr, weight_decay=ctx.cfg.optim.weight_decay
    )
    start_epoch, history = 0, []
    if own is not None:
        optimizer.load_state_dict(own.optimizer)
        start_epoch, history = own.epoch, list(own.metrics)
        if own.rng is not None:
            torch.set_rng_state(own.rng["torch"])
    total = epochs if epochs is not None else getattr(ctx.cfg.optim, f"epochs_{stage}")
    model = _wrap(stage, backbone, shift, ctx)
    average, avg_from = stage_average(stage, backbone, own, ctx, total)
    for epoch in range(start_epoch, total):
        t0 = time.perf_counter()
        lr = ctx.cfg.optim.lr_at(epoch, total)
        for group in optimizer.param_groups:
            group["lr"] = lr
        in_mean = average if epoch >= avg_from else None
        loss = train_one_epoch(stage, model, backbone, shift, optimizer, ctx, epoch, in_mean)
        row = {"stage": stage, "epoch": epoch + 1, "lr": lr, "train_loss": loss}
        if measured is not None and epoch == start_epoch:
            row["bn_scans"] = measured  # the held statistics were measured on these scans
        if average is not None and epoch + 1 == total:
            row["swa_steps"] = average.count
            finish_stage_average(average, backbone, ctx, epoch)
            average = None
        if (epoch + 1) % max(ctx.cfg.optim.val_every, 1) == 0 or epoch + 1 == total:
            row.update(_validate(stage, backbone, shift, ctx))
        row["seconds"] = time.perf_counter() - t0
        history.append(row)
        if ctx.info.is_main:
            ckpt = _make_checkpoint(stage, epoch + 1, ctx, backbone, shift, optimizer, history)
            if average is not None and average.count:  # only once the window has begun
                ckpt.average = average.state_dict()
            save_checkpoint(ckpt, path)
            write_metrics_csv(ctx.run_dir, stage, history)
        ddp.barrier(ctx.info)
    if start_epoch >= total and ctx.info.is_main and not path.is_file():
        save_checkpoint(_make_checkpoint(stage, 0, ctx, backbone, shift, optimizer, history), path)
    return path


def _wrap(stage: str, backbone: nn.Module, shift: nn.Module | None, ctx: TrainContext):
    """The modules that receive gradients, DDP-wrapped when distributed."""
    frozen = stage == "ds" and ctx.cfg.dynamic_shift.freeze_backbone
    mods = {"backbone": backbone, "shift": shift}
    if not ctx.info.enabled:
        return mods
    from torch.nn.parallel import DistributedDataParallel as DDP

    dev_ids = [ctx.info.device.index] if ctx.info.device.type == "cuda" else None
    if not frozen:
        mods["backbone"] = DDP(backbone, device_ids=dev_ids, find_unused_parameters=True)
    if shift is not None:
        mods["shift"] = DDP(shift, device_ids=dev_ids, find_unused_parameters=True)
    return mods


def train_one_epoch(
    stage: str,
    model: dict[str, nn.Module | None],
    backbone: nn.Module,
    shift: nn.Module | None,
    optimizer: torch.optim.Optimizer,
    ctx: TrainContext,
    epoch: int,
    average: StepAverage | None = None,
) -> float:
    """One pass over this rank's shard of the training set; returns the mean loss over ranks.

    ``average``, when given, takes the backbone's weights after every optimiser step."""
    from tqdm import tqdm

    frozen = stage == "ds" and ctx.cfg.dynamic_shift.freeze_backbone
    backbone.train(not frozen)
    held = ctx.cfg.optim.freeze_bn and not frozen
    if held:
        hold_batchnorm_statistics(backbone)
    if shift is not None:
        shift.train()
    ctx.train_set.set_epoch(epoch)
    order = ddp.shard_order(len(ctx.train_set), epoch, ctx.cfg.optim.seed, ctx.info, shuffle=True)
    bs = ctx.cfg.optim.batch_size
    batches = [order[i : i + bs] for i in range(0, len(order), bs)]
    weights = torch.tensor(ctx.class_weights, dtype=torch.float32, device=ctx.info.device)
    losses = []
    bar = tqdm(batches, desc=f"{stage} epoch {epoch + 1}", disable=not ctx.progress, leave=False)
    with statistics_noise(backbone, ctx.cfg.optim.bn_noise if held else 0.0):
        for idx in bar:
            samples = [ctx.train_set[i] for i in idx]
            optimizer.zero_grad(set_to_none=True)
            loss = step_loss(stage, model, samples, ctx, weights, frozen)
            loss.backward()
            optimizer.step()
            if average is not None:
                average.update(backbone)
            losses.append(float(loss.detach()))
            bar.set_postfix(loss=f"{losses[-1]:.3f}")
    mean = float(np.mean(losses)) if losses else 0.0
    return ddp.mean_scalar(mean, len(losses), ctx.info)


def _validate(stage: str, backbone: nn.Module, shift: nn.Module | None, ctx: TrainContext) -> dict:
    """Validation metrics (fractions) of this stage, accumulated over every rank."""
    from panoptic_bench.dsnet.data.density import with_density_policy
    from panoptic_bench.dsnet.inference.predictor import Predictor, evaluate_dataset

    predictor = with_density_policy(
        Predictor(
            backbone, shift if stage == "ds" else None, ctx.cfg, ctx.class_map, ctx.info.device
        )
    )
    summary = evaluate_dataset(
        predictor,
        ctx.val_set,
        indices=ddp.eval_shard(len(ctx.val_set), ctx.info),
        panoptic=stage != "semantic",
        info=ctx.info,
        progress=ctx.progress,
    )
    keys = ("mIoU", "PQ", "PQ_th", "PQ_st", "SQ", "RQ") if stage != "semantic" else ("mIoU",)
    return {f"val_{k}": summary[k] for k in keys if k in summary}


def _make_checkpoint(stage, epoch, ctx, backbone, shift, optimizer, history) -> Checkpoint:
    return Checkpoint(
        stage=stage,
        epoch=epoch,
        config=ctx.cfg,
        class_map=ctx.class_map,
        backbone={k: v.detach().cpu() for k, v in backbone.state_dict().items()},
        shift=None if shift is None else {k: v.cpu() for k, v in shift.state_dict().items()},
        optimizer=optimizer.state_dict(),
        rng={"torch": torch.get_rng_state()},
        class_weights=ctx.class_weights,
        metrics=list(history),
    )
