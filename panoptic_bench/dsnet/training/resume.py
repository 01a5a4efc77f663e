"""What a ``--resume`` may continue: only the run the checkpoint belongs to.

A stage checkpoint stores the config it was trained with. Resuming it with another config (say a
different ``--val-sequences``, or an edited YAML) would silently train the rest of the epochs on
other data or settings, and the result would match neither recipe. :func:`check_resumable`
refuses that, naming every differing key.
"""

from __future__ import annotations

from pathlib import Path

from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.errors import InputError

__all__ = ["config_differences", "check_resumable"]


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
