"""``metrics.csv`` of a training run: one row per stage and epoch."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from panoptic_bench.dsnet.checkpoint import STAGES
from panoptic_bench.io import write_text

__all__ = ["CSV_FIELDS", "write_metrics_csv"]

CSV_FIELDS = (
    "stage",
    "epoch",
    "lr",
    "train_loss",
    "val_mIoU",
    "val_PQ",
    "val_PQ_th",
    "val_PQ_st",
    "val_SQ",
    "val_RQ",
    "seconds",
)


def write_metrics_csv(run_dir: Path, stage: str, history: list[dict]) -> None:
    """Rewrite ``metrics.csv``: rows of the other stages kept, this stage's rows replaced."""
    path = run_dir / "metrics.csv"
    rows = []
    if path.is_file():
        with open(path, newline="") as fh:
            rows = [r for r in csv.DictReader(fh) if r.get("stage") != stage]
    rows += history
    rows.sort(key=lambda r: (STAGES.index(r["stage"]), int(r["epoch"])))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_FIELDS, extrasaction="ignore")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: _fmt(r.get(k, "")) for k in CSV_FIELDS})
    write_text(path, buf.getvalue())


def _fmt(value) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)
