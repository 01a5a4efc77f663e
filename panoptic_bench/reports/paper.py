"""The DS-Net paper's published numbers (Tables 1-8), typed in once as data.

The numbers live in the packaged file ``panoptic_bench/data/paper_tables.yaml``; this module
loads them and hands them out as :class:`pandas.DataFrame` objects in percent, exactly as printed
(``NaN`` where the paper prints "-").

Example
-------
>>> from panoptic_bench.reports.paper import paper_table
>>> paper_table(1).loc["DS-Net", "PQ"]
57.7
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import yaml

PAPER_TABLES_PATH = Path(__file__).resolve().parents[1] / "data" / "paper_tables.yaml"

#: Metric keys of the Tables 1/2/3 layout, as in ``scores.json`` ``"all"``.
MAIN_METRICS: tuple[str, ...] = (
    "PQ",
    "PQ_dagger",
    "RQ",
    "SQ",
    "PQ_th",
    "RQ_th",
    "SQ_th",
    "PQ_st",
    "RQ_st",
    "SQ_st",
    "mIoU",
)
#: Our column beside the Tables 1-3 layout (not in the paper): mIoU over the classes with ground truth.
PRESENT_METRIC = "mIoU_present"
#: Metric keys of Tables 4 and 5.
SHORT_METRICS: tuple[str, ...] = ("PQ", "PQ_dagger", "RQ", "SQ", "mIoU")
#: How each metric key is printed in a table header (markdown / CSV).
METRIC_LABELS: dict[str, str] = {
    "PQ": "PQ",
    "PQ_dagger": "PQ†",
    "RQ": "RQ",
    "SQ": "SQ",
    "PQ_th": "PQ_Th",
    "RQ_th": "RQ_Th",
    "SQ_th": "SQ_Th",
    "PQ_st": "PQ_St",
    "RQ_st": "RQ_St",
    "SQ_st": "SQ_St",
    "mIoU": "mIoU",
    PRESENT_METRIC: "mIoU (present)",
}
#: The per-class table of each panoptic quantity.
PER_CLASS_TABLE: dict[str, int] = {"PQ": 6, "RQ": 7, "SQ": 8}


@dataclass(frozen=True)
class PaperTable:
    """One published table.

    Attributes
    ----------
    number : int
        Table number in the paper (1-8).
    caption : str
        The paper's caption (shortened).
    dataset : str
        ``"semantickitti"`` or ``"nuscenes"``.
    split : str
        ``"val"`` or ``"test"``.
    index : str
        Name of the row key (``"Method"``, ``"Bandwidth candidates (m)"``, ...).
    frame : pandas.DataFrame
        Rows x metric (or class) columns, float64 percent; ``NaN`` for "-".
    """

    number: int
    caption: str
    dataset: str
    split: str
    index: str
    frame: pd.DataFrame


@functools.lru_cache(maxsize=1)
def _load() -> dict:
    with open(PAPER_TABLES_PATH, encoding="utf-8") as fh:
        return yaml.safe_load(fh)


def paper_table_info(number: int) -> PaperTable:
    """Return table ``number`` of the paper with its caption, dataset and split.

    Parameters
    ----------
    number : int
        1 to 8.

    Returns
    -------
    PaperTable
        ``frame`` is a fresh copy; modifying it does not change later calls.
    """
    tables = _load()["tables"]
    if number not in tables:
        raise KeyError(f"the paper has Tables 1-8; no table {number}")
    spec = tables[number]
    labels = [str(row[0]) for row in spec["rows"]]
    values = [[float("nan") if v is None else float(v) for v in row[1:]] for row in spec["rows"]]
    frame = pd.DataFrame(
        values, index=pd.Index(labels, name=spec["index"]), columns=spec["columns"]
    )
    return PaperTable(
        number=number,
        caption=spec["caption"],
        dataset=spec["dataset"],
        split=spec["split"],
        index=spec["index"],
        frame=frame,
    )


def paper_table(number: int) -> pd.DataFrame:
    """Table ``number`` (1-8) of the paper as a DataFrame in percent.

    Tables 1-3: index ``Method``, columns :data:`MAIN_METRICS`. Table 4: index the bandwidth
    candidates as printed (``"0.2, 1.7, 3.2"``), Table 5: the number of iterations as a string;
    columns :data:`SHORT_METRICS`. Tables 6/7/8: index ``Method``, first column the row mean
    (``PQ`` / ``RQ`` / ``SQ``) then the 19 SemanticKITTI classes (8 things, then 11 stuff).
    """
    return paper_table_info(number).frame


def semantickitti_classes() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The paper's SemanticKITTI class order: ``(things, stuff)`` (8 and 11 names)."""
    data = _load()
    return tuple(data["semantickitti_things"]), tuple(data["semantickitti_stuff"])


def nuscenes_class_counts() -> tuple[int, int]:
    """Number of things and stuff classes of the paper's nuScenes benchmark: ``(10, 6)``."""
    data = _load()
    return int(data["nuscenes_num_things"]), int(data["nuscenes_num_stuff"])


def main_table_for(dataset: str, split: str) -> int | None:
    """The Tables 1/2/3 number matching ``dataset``/``split``, or None when the paper has none.

    SemanticKITTI ``test`` is Table 2, any other SemanticKITTI split compares with Table 1
    (validation), nuScenes with Table 3.
    """
    dataset = normalize_name(dataset)
    if dataset == "semantickitti":
        return 2 if split == "test" else 1
    if dataset == "nuscenes":
        return 3
    return None


def normalize_name(name: str) -> str:
    """Canonical spelling for matching names: lower case, ``-``/``_``/spaces removed."""
    return "".join(ch for ch in str(name).lower() if ch not in " -_")
