"""Rendering a :class:`ReportTable` as markdown, CSV and LaTeX (deterministic text, no pandas
formatting extras needed).

The frame of a report table holds the text columns ``Source`` (``paper`` / ``ours``), the row
label (``Method``, ``Bandwidth candidates (m)``, ...) and ``Data``, followed by numeric metric
columns in percent (``NaN`` printed as ``-``).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from panoptic_bench.io import write_text
from panoptic_bench.reports.paper import METRIC_LABELS

TEXT_COLUMNS = ("Source", "Data")

_LATEX_LABELS = {
    "PQ_dagger": r"PQ$^\dagger$",
    "PQ_th": r"PQ$^\mathrm{Th}$",
    "RQ_th": r"RQ$^\mathrm{Th}$",
    "SQ_th": r"SQ$^\mathrm{Th}$",
    "PQ_st": r"PQ$^\mathrm{St}$",
    "RQ_st": r"RQ$^\mathrm{St}$",
    "SQ_st": r"SQ$^\mathrm{St}$",
}
_LATEX_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "†": r"$^\dagger$",
}


@dataclass(frozen=True)
class ReportTable:
    """A table ready to be written.

    Attributes
    ----------
    name : str
        File stem, e.g. ``"table1_semantickitti_val"``.
    title : str
        One-line title (markdown heading / LaTeX caption).
    label : str
        Name of the row-label column (``"Method"``, ``"Bandwidth candidates (m)"``...).
    frame : pandas.DataFrame
        Columns ``Source``, ``label``, ``Data``, then numeric columns (percent, NaN = "-").
    note : str
        Sentence printed under the table.
    """

    name: str
    title: str
    label: str
    frame: pd.DataFrame
    note: str = ""

    @property
    def value_columns(self) -> list[str]:
        """The numeric columns (metric keys or class names)."""
        return [c for c in self.frame.columns if c not in (*TEXT_COLUMNS, self.label)]


def _fmt(value: object, digits: int = 1) -> str:
    if isinstance(value, str):
        return value
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{float(value):.{digits}f}"


def _header(column: str) -> str:
    return METRIC_LABELS.get(column, column)


def _md_cell(text: str) -> str:
    return text.replace("|", r"\|").replace("*", r"\*")


def to_markdown(table: ReportTable) -> str:
    """Markdown section: ``### title``, a pipe table (ours in bold) and the note."""
    cols = list(table.frame.columns)
    head = "| " + " | ".join(_md_cell(_header(c)) for c in cols) + " |"
    align = "|" + "|".join("---:" if c in table.value_columns else "---" for c in cols) + "|"
    lines = [f"### {table.title}", "", head, align]
    for _, row in table.frame.iterrows():
        cells = [_md_cell(_fmt(row[c])) for c in cols]
        if row["Source"] == "ours":
            cells[:2] = [f"**{cells[0]}**", f"**{cells[1]}**"]
        lines.append("| " + " | ".join(cells) + " |")
    if table.note:
        lines += ["", table.note]
    return "\n".join(lines) + "\n"


def to_csv(table: ReportTable) -> str:
    """CSV with the raw column keys (``PQ_dagger``...), values in percent with 2 decimals."""
    buf = io.StringIO()
    table.frame.to_csv(buf, index=False, float_format="%.2f", lineterminator="\n", na_rep="")
    return buf.getvalue()


def _tex(text: str) -> str:
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in text)


def to_latex(table: ReportTable) -> str:
    """A booktabs ``table`` environment; a rule separates the paper's rows from ours."""
    cols = list(table.frame.columns)
    spec = "".join("r" if c in table.value_columns else "l" for c in cols)
    header = " & ".join(_LATEX_LABELS.get(c, _tex(_header(c))) for c in cols) + r" \\"
    lines = [
        r"% requires \usepackage{booktabs}",
        r"\begin{table}[t]",
        r"\centering",
        r"\small",
        rf"\caption{{{_tex(table.title)}}}",
        rf"\label{{tab:{table.name}}}",
        rf"\begin{{tabular}}{{{spec}}}",
        r"\toprule",
        header,
        r"\midrule",
    ]
    previous = None
    for _, row in table.frame.iterrows():
        if previous is not None and row["Source"] != previous:
            lines.append(r"\midrule")
        previous = row["Source"]
        cells = [_tex(_fmt(row[c])) for c in cols]
        if row["Source"] == "ours":
            cells[:2] = [rf"\textbf{{{cells[0]}}}", rf"\textbf{{{cells[1]}}}"]
        lines.append(" & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if table.note:
        lines.append(rf"\par\smallskip\footnotesize {_tex(table.note)}")
    lines.append(r"\end{table}")
    return "\n".join(lines) + "\n"


def write_table(table: ReportTable, out_dir: str | Path) -> dict[str, Path]:
    """Write ``name.md``, ``name.csv`` and ``name.tex`` atomically into ``out_dir``.

    Returns
    -------
    dict
        ``{"md": path, "csv": path, "tex": path}``.
    """
    out_dir = Path(out_dir)
    paths = {ext: out_dir / f"{table.name}.{ext}" for ext in ("md", "csv", "tex")}
    write_text(paths["md"], to_markdown(table))
    write_text(paths["csv"], to_csv(table))
    write_text(paths["tex"], to_latex(table))
    return paths
