"""Where a stage starts: its own checkpoint (``--resume``), an ``--init``, or the previous stage's.

What a ``--resume`` may continue: only the run the checkpoint belongs to.

A stage checkpoint stores the config it was trained with. Resuming it with another config (say a
different ``--val-sequences``, or an edited YAML) would silently train the rest of the epochs on
other data or settings, and the result would match neither recipe. :func:`check_resumable`
refuses that, naming every differing key.
"""

from __future__ import annotations

from pathlib import Path

from panoptic_bench.dsnet.checkpoint import STAGES, Checkpoint, load_checkpoint
from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.errors import InputError

__all__ = ["check_resumable", "checkpoint_path", "config_differences", "start_checkpoint"]


def checkpoint_path(run_dir: str | Path, stage: str) -> Path:
    """``run_dir/checkpoints/<stage>.pt``."""
    return Path(run_dir) / "checkpoints" / f"{stage}.pt"


def start_checkpoint(run_dir: str | Path, stage: str, init: str | Path | None) -> Checkpoint | None:
    """The weights a fresh ``stage`` starts from: ``init``, else the previous stage's checkpoint.

    None for a ``semantic`` stage without ``init`` (random weights); a missing previous stage is
    an :class:`InputError` naming its path.
    """
    if init is not None:
        return load_checkpoint(init)
    if stage == "semantic":
        return None
    prev = checkpoint_path(run_dir, STAGES[STAGES.index(stage) - 1])
    if not prev.is_file():
        raise InputError(
            f"stage {stage!r} starts from the previous stage's checkpoint; train it first "
            "(--stage all) or pass an initial checkpoint",
            prev,
        )
    return load_checkpoint(prev)


def config_differences(stored: DSNetConfig, cfg: DSNetConfig) -> list[str]:
    """``"section.key: <stored> in the checkpoint, <cfg> now"`` for every key that differs."""
    a, b = stored.to_dict(), cfg.to_dict()
    return [
        f"{sec}.{key}: {a.get(sec, {}).get(key)!r} in the checkpoint, {b.get(sec, {}).get(key)!r} now"
        for sec in sorted(set(a) | set(b))
        for key in sorted(set(a.get(sec, {})) | set(b.get(sec, {})))
        if a.get(sec, {}).get(key) != b.get(sec, {}).get(key)
    ]


def check_resumable(stored: DSNetConfig, cfg: DSNetConfig, path: str | Path) -> None:
    """Raise :class:`InputError` naming ``path`` unless ``cfg`` equals the checkpoint's config."""
    diff = config_differences(stored, cfg)
    if diff:
        more = f"; {len(diff) - 4} more" if len(diff) > 4 else ""
        raise InputError(
            f"cannot resume with a different config ({'; '.join(diff[:4])}{more}): "
            "give the run's config.yaml and the same options",
            path,
        )
