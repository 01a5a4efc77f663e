"""SemanticKITTI tree utilities: validation of a prediction tree and raw <-> train id remapping."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.errors import InputError
from panoptic_bench.evaluation.output import check_output_location
from panoptic_bench.evaluation.semantickitti import (
    check_label_ids,
    prediction_problems,
    scan_point_count,
)
from panoptic_bench.io import ensure_output_dir

__all__ = ["remap_label", "remap_tree", "validate_semantickitti"]


def validate_semantickitti(
    dataset: str | Path,
    predictions: str | Path,
    *,
    split: str | None = "valid",
    sequences: Sequence[int | str] | None = None,
    progress: bool | None = None,
) -> tuple[int, list[str]]:
    """Check a prediction tree against a dataset tree and list **every** problem found.

    Checked: sequence directories (missing, unreadable, empty), scan sizes (multiple of 16 bytes),
    missing and extra prediction files, prediction sizes (multiple of 4 bytes), one label per point,
    known raw label ids; ground-truth labels the same way where a ``labels/`` directory exists.

    Returns
    -------
    (int, list of str)
        Number of scans found and the problems, each ``"path: message"``.
    """
    problems: list[str] = []
    refs: list[sk.ScanRef] = []
    for seq_dir in sk.sequence_dirs(dataset, split=split, sequences=sequences):
        try:
            refs.extend(sk.list_sequence(seq_dir))
        except InputError as exc:
            problems.append(str(exc))
    missing, extra = prediction_problems(refs, predictions)
    problems += missing + extra
    missing_set = {m.split(": ", 1)[0] for m in missing}
    disable = None if progress is None else not progress
    for ref in tqdm(refs, desc="validate", unit="scan", disable=disable):
        try:
            n = scan_point_count(ref.scan)
        except InputError as exc:
            problems.append(str(exc))
            n = None
        checks = [(sk.prediction_path(predictions, ref), "prediction")]
        if ref.label.parent.is_dir():
            checks.append((ref.label, "ground truth"))
        for path, what in checks:
            if str(path) in missing_set:
                continue
            try:
                labels = sk.read_labels(path)
                if n is not None:
                    check_label_ids(labels, n, path, what)
            except InputError as exc:
                problems.append(str(exc))
    return len(refs), problems


def remap_label(
    labels: np.ndarray, *, inverse: bool = False, path: Path | None = None
) -> np.ndarray:
    """Map the semantic bits of uint32 labels raw -> train (or train -> raw), keeping instance bits.

    Parameters
    ----------
    labels : array of shape (n,), uint32
    inverse : bool
        False: raw ids -> train ids 0..19; True: train ids -> raw ids.
    path : Path, optional
        File named in errors.

    Returns
    -------
    ndarray of shape (n,), uint32
    """
    labels = np.asarray(labels, dtype=np.uint32)
    sem = labels & 0xFFFF
    if inverse:
        bad = sem >= len(sk.LABELS.inv_lut)
        hint = "ids must be train ids 0-19; is the file already raw? (drop --inverse)"
        new = sk.LABELS.inv_lut[np.where(bad, 0, sem)]
    else:
        bad = ~sk.LABELS.valid_raw[sem]
        hint = "ids must be raw SemanticKITTI ids; is the file already in train ids? (--inverse)"
        new = sk.LABELS.train_lut[sem]
    if bad.any():
        shown = ", ".join(str(i) for i in np.unique(sem[bad])[:8])
        raise InputError(f"{int(bad.sum())} points with unexpected ids ({shown}): {hint}", path)
    return (labels & np.uint32(0xFFFF0000)) | new.astype(np.uint32)


def remap_tree(
    input_dir: str | Path,
    output_dir: str | Path,
    *,
    inverse: bool = False,
    progress: bool | None = None,
) -> int:
    """Remap every ``.label`` file under ``input_dir`` into the same relative path under ``output_dir``.

    All files are checked before anything is written; the output may not lie inside the input.

    Returns
    -------
    int
        Number of files written.
    """
    src = Path(input_dir)
    if not src.is_dir():
        raise InputError("input directory not found", src)
    try:
        files = sorted(src.rglob("*.label"))
    except OSError as exc:
        raise InputError(f"cannot read input directory ({exc})", src) from None
    if not files:
        raise InputError("no .label files found under the input directory", src)
    check_output_location(output_dir, (src,))
    disable = None if progress is None else not progress
    for path in tqdm(files, desc="check", unit="file", disable=disable):
        remap_label(sk.read_labels(path), inverse=inverse, path=path)
    out = ensure_output_dir(output_dir, inputs=(src,))
    for path in tqdm(files, desc="remap", unit="file", disable=disable):
        new = remap_label(sk.read_labels(path), inverse=inverse, path=path)
        sk.write_labels(out / path.relative_to(src), new)
    return len(files)
