"""Import an official DS-Net checkpoint (spconv 1.x era) as a panoptic-bench checkpoint.

:func:`import_official` reads the file the official ``save_checkpoint`` writes (a dict with
``model_state``) or a bare state dict, strips ``module.`` prefixes (DataParallel / DDP),
detects the training step from the keys (:data:`~.keymap.STEP_PREFIXES`), maps and reshapes
every tensor (:func:`~.keymap.official_rules`), loads the result strictly into the official
network of :func:`official_config`, and only then writes the checkpoint. Any unreadable file,
foreign model, unmapped, missing or wrong-shaped key is one :class:`InputError` naming it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from panoptic_bench.dsnet.config import DSNetConfig
from panoptic_bench.dsnet.official.keymap import (
    OFFICIAL_DIMS,
    STEP_NAMES,
    STEP_PREFIXES,
    KeyRule,
    official_rules,
)
from panoptic_bench.errors import InputError, InputErrors

__all__ = ["ImportResult", "convert_state", "import_official", "official_config", "read_official"]

#: Config of the official network (released SemanticKITTI settings, ``cfgs/release/dsnet.yaml``).
OFFICIAL_CONFIG: dict[str, dict[str, Any]] = {
    "model": {
        "variant": "official",
        "init_size": 32,
        "point_hidden": [64, 128, 256],
        "point_feature_dim": 64,
        "voxel_feature_dim": 16,
        "offset_hidden": 32,
    },
    "dynamic_shift": {"bandwidths": [0.2, 1.7, 3.2], "iterations": 4, "max_seeds": 10000},
    "inference": {"clusterer": "meanshift", "bandwidth": 1.2, "ds_bandwidth": 0.65},
    "data": {"format": "semantickitti", "num_classes": 20},
}

# Keys of models that are not the single-frame DS-Net, with what they are.
_FOREIGN = (
    ("cylinder_3d_", "a Cylinder3D checkpoint (cylinder_3d_* keys)"),
    ("tracking_head", "a 4D-DS-Net / DS-Net tracking checkpoint (tracking_head keys)"),
    ("siamese", "a DS-Net siamese tracking checkpoint (siamese keys)"),
)
_IGNORED = {"sem_loss.weight"}  # weighted-CE buffer: kept as class_weights


@dataclass
class ImportResult:
    """What :func:`convert_state` produced.

    Attributes
    ----------
    step : int
        Official training step (1 semantic, 2 offset, 3 DS-Net).
    backbone, shift : dict of str to torch.Tensor
        Our state dicts (``shift`` is None before step 3).
    rows : list of tuple
        ``(official key, official shape, our key, our shape, how)`` for ``--print-map``.
    class_weights : list of float or None
        ``sem_loss.weight`` when present.
    epoch : int
    """

    step: int
    backbone: dict[str, torch.Tensor]
    shift: dict[str, torch.Tensor] | None
    rows: list[tuple[str, tuple, str, tuple, str]] = field(default_factory=list)
    class_weights: list[float] | None = None
    epoch: int = 0

    def map_text(self) -> str:
        """The key mapping, one line per tensor."""
        lines = [
            f"official DS-Net step {self.step} ({STEP_NAMES[self.step]}): {len(self.rows)} rows"
        ]
        for off, oshape, ours, shape, how in self.rows:
            lines.append(f"{off} {list(oshape)} -> {ours} {list(shape)} ({how})")
        return "\n".join(lines)


def official_config() -> DSNetConfig:
    """The official network's config (``model.variant: official``, paper SemanticKITTI values)."""
    return DSNetConfig.from_dict(OFFICIAL_CONFIG)


def read_official(path: str | Path) -> tuple[dict[str, torch.Tensor], int]:
    """The state dict (``module.`` stripped) and epoch of an official checkpoint file.

    Raises
    ------
    InputError
        Missing, unreadable or truncated file; not a state dict; a panoptic-bench checkpoint.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("official checkpoint not found (download links: DS-Net README)", path)
    try:
        raw = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure is a user-file problem
        msg = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise InputError(
            f"cannot read as a PyTorch checkpoint (not a checkpoint, truncated, or holding "
            f"pickled objects other than tensors: {type(exc).__name__}: {msg})",
            path,
        ) from None
    if isinstance(raw, dict) and str(raw.get("format", "")).startswith("panoptic-bench"):
        raise InputError("already a panoptic-bench checkpoint; use it directly", path)
    epoch = 0
    if isinstance(raw, dict) and "model_state" in raw:
        epoch = raw.get("epoch") if isinstance(raw.get("epoch"), int) else 0
        raw = raw["model_state"]
    if (
        not isinstance(raw, dict)
        or not raw
        or not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in raw.items())
    ):
        raise InputError(
            "not a DS-Net checkpoint: expected a state dict of tensors or a dict with "
            "'model_state' (as the official save_checkpoint writes)",
            path,
        )
    state = {k.removeprefix("module."): v for k, v in raw.items()}
    return state, int(epoch or 0)


def detect_step(state: dict[str, torch.Tensor], source: str | Path | None = None) -> int:
    """Official training step of a state dict from its top-level module names."""
    for marker, what in _FOREIGN:
        hit = next((k for k in state if marker in k), None)
        if hit is not None:
            raise InputError(
                f"{what}, e.g. {hit!r}: not supported; import-dsnet reads the released "
                "single-frame DS-Net checkpoints (steps 1-3)",
                source,
            )
    tops = {k.split(".", 1)[0] for k in state}
    if not tops & set(STEP_PREFIXES[1]):
        sample = ", ".join(sorted(state)[:3])
        raise InputError(
            f"not a DS-Net checkpoint: none of the modules {', '.join(STEP_PREFIXES[1])} "
            f"(first keys: {sample})",
            source,
        )
    if tops & set(STEP_PREFIXES[3]):
        return 3
    return 2 if tops & set(STEP_PREFIXES[2]) else 1


def _convert(rule: KeyRule, value: torch.Tensor) -> tuple[torch.Tensor, str] | None:
    """Our tensor for one official tensor, or None when its shape fits no known layout."""
    shape = tuple(value.shape)
    if not rule.conv:
        return (value.clone(), "copy") if shape == rule.shape else None
    *k, n_in, n_out = rule.shape
    if shape == rule.shape:  # spconv 1.x (k0, k1, k2, in, out)
        return value.reshape(math.prod(k), n_in, n_out).clone(), "spconv1 reshape"
    if shape == (n_out, *k, n_in):  # spconv 2.x (out, k0, k1, k2, in)
        w = value.permute(1, 2, 3, 4, 0).reshape(math.prod(k), n_in, n_out)
        return w.contiguous().clone(), "spconv2 permute+reshape"
    return None


def convert_state(
    state: dict[str, torch.Tensor], source: str | Path | None = None, epoch: int = 0
) -> ImportResult:
    """Map an official state dict onto our backbone (and dynamic-shift) state dicts.

    Raises
    ------
    InputErrors
        Every unmapped, missing or wrong-shaped key, named.
    """
    step = detect_step(state, source)
    rules = official_rules(step)
    known = {r.official for r in rules}
    problems = [
        f"unmapped key {k!r} {list(v.shape)} (not in the official step-{step} layout)"
        for k, v in state.items()
        if k not in known and k not in _IGNORED
    ]
    backbone: dict[str, torch.Tensor] = {}
    shift: dict[str, torch.Tensor] = {}
    rows = []
    for r in rules:
        if r.official not in state:
            problems.append(f"missing key {r.official!r} (expected shape {list(r.shape)})")
            continue
        got = _convert(r, state[r.official])
        if got is None:
            problems.append(
                f"wrong shape for {r.official!r}: {list(state[r.official].shape)}, expected "
                f"{list(r.shape)}" + (" (spconv 1.x) or the spconv 2.x order" if r.conv else "")
            )
            continue
        tensor, how = got
        (backbone if r.target == "backbone" else shift)[r.ours] = tensor
        rows.append((r.official, tuple(state[r.official].shape), r.ours, tuple(tensor.shape), how))
    if problems:
        where = f" in {source}" if source else ""
        raise InputErrors(problems, header=f"cannot import the official checkpoint{where}")
    weights = state.get("sem_loss.weight")
    cw = None
    if weights is not None and tuple(weights.shape) == (OFFICIAL_DIMS["num_classes"],):
        cw = [float(x) for x in weights]
    return ImportResult(step, backbone, shift if step == 3 else None, rows, cw, epoch)


def import_official(
    src: str | Path, dst: str | Path, *, print_map: bool = False
) -> tuple[Path, ImportResult]:
    """Convert the official checkpoint ``src`` into our checkpoint ``dst`` (atomic write).

    A step-1 checkpoint has no offset head: ours gets a freshly initialised one (seed 0), as the
    official step 2 starts. The written checkpoint loads strictly into the official network and
    works with ``infer``, ``eval`` and ``checkpoint show`` unchanged.

    Returns
    -------
    dst : Path
    result : ImportResult
    """
    from panoptic_bench.datasets.semantickitti import LABELS
    from panoptic_bench.dsnet.checkpoint import (
        Checkpoint,
        build_backbone,
        build_shift,
        save_checkpoint,
    )
    from panoptic_bench.dsnet.data.datasets import ClassMap

    state, epoch = read_official(src)
    res = convert_state(state, src, epoch)
    if print_map:
        print(res.map_text())
    cfg = official_config()
    lab = LABELS
    cmap = ClassMap("semantickitti", lab.class_names, lab.thing_ids, lab.stuff_ids, lab.ignore_ids)
    with torch.random.fork_rng(devices=[]):  # seed-0 init, the caller's RNG untouched
        torch.manual_seed(0)
        backbone = build_backbone(cfg, cmap.num_classes)
    full = backbone.state_dict()
    unset = sorted(set(full) - set(res.backbone))
    if res.step >= 2 and unset:
        raise InputError(f"internal key map incomplete, no value for {unset[0]!r}", src)
    full.update(res.backbone)
    backbone.load_state_dict(full, strict=True)  # shapes are checked again here
    shift_state = None
    if res.shift is not None:
        shift = build_shift(cfg, cfg.model.init_size)
        shift.load_state_dict(res.shift, strict=True)
        shift_state = shift.state_dict()
    ckpt = Checkpoint(
        stage=STEP_NAMES[res.step],
        epoch=res.epoch,
        config=cfg,
        class_map=cmap,
        backbone=backbone.state_dict(),
        shift=shift_state,
        class_weights=res.class_weights,
        metrics=[{"imported_from": str(src), "official_step": res.step}],
    )
    dst = Path(dst)
    save_checkpoint(ckpt, dst)
    return dst, res
