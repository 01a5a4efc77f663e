"""Report tables and build_report end to end: JSON run directories in, exact files out."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from panoptic_bench.cli import main
from panoptic_bench.errors import InputError
from panoptic_bench.reports.index import build_report, report_command
from panoptic_bench.reports.render import to_csv, to_latex, to_markdown
from panoptic_bench.reports.runs import RunMeta, load_run, load_runs
from panoptic_bench.reports.tables import (
    bandwidth_table,
    build_tables,
    format_bandwidths,
    iterations_table,
    main_tables,
    per_class_tables,
    range_table,
)

KEYS = ("PQ", "PQ_dagger", "SQ", "RQ", "PQ_th", "SQ_th", "RQ_th", "PQ_st", "SQ_st", "RQ_st")


def _scores(pq: float, **extra) -> dict:
    overall = {k: pq for k in KEYS} | {"mIoU": 0.625, "accuracy": 0.9}
    return {"all": overall, **extra}


def _run(root: Path, name: str, scores: dict, meta: dict | None = None) -> Path:
    d = root / name
    d.mkdir(parents=True)
    (d / "scores.json").write_text(json.dumps(scores))
    if meta is not None:
        (d / "run.json").write_text(json.dumps(meta))
    return d


EXPECTED_TABLE5 = """\
### Table 5: number of dynamic shifting iterations, SemanticKITTI validation set (paper) and ours

| Source | Number of iterations | Data | PQ | PQ† | RQ | SQ | mIoU |
|---|---|---|---:|---:|---:|---:|---:|
| paper | 1 | SemanticKITTI val (paper) | 57.0 | 62.6 | 67.4 | 77.3 | 63.5 |
| paper | 2 | SemanticKITTI val (paper) | 57.6 | 63.1 | 67.8 | 77.5 | 63.6 |
| paper | 3 | SemanticKITTI val (paper) | 57.7 | 63.3 | 68.0 | 77.6 | 63.4 |
| paper | 4 | SemanticKITTI val (paper) | 57.7 | 63.4 | 68.0 | 77.6 | 63.5 |
| paper | 5 | SemanticKITTI val (paper) | 57.5 | 63.2 | 67.7 | 77.6 | 63.4 |
| **ours** | **2** | synthetic world, seq 08 | 40.0 | 40.0 | 40.0 | 40.0 | 62.5 |
| **ours** | **4** | synthetic world, seq 08 | 51.2 | 51.2 | 51.2 | 51.2 | 62.5 |

All values in %. Rows marked paper: published numbers of the DS-Net paper (Hong et al., CVPR \
2021, Table 5), SemanticKITTI validation set. Rows marked ours: computed by panoptic-bench on \
the data named in the Data column; they compare number-for-number with the paper only when that \
data is the paper's.
"""


def test_table5_end_to_end_exact_markdown(tmp_path):
    """JSON run directories -> build_report -> tables/table5_iterations.md, byte for byte."""
    meta = {"method": "DS-Net", "dataset": "semantickitti", "data": "synthetic world, seq 08"}
    a = _run(tmp_path, "it4", _scores(0.51234), meta | {"iterations": 4})
    b = _run(tmp_path, "it2", _scores(0.4), meta | {"iterations": 2})
    _run(tmp_path, "other", _scores(0.3), {"method": "BFS"})  # no iterations: not in Table 5
    index = build_report([a, b, tmp_path / "other"], tmp_path / "report")
    assert index == (tmp_path / "report" / "index.md").resolve()
    text = (tmp_path / "report" / "tables" / "table5_iterations.md").read_text(encoding="utf-8")
    assert text == EXPECTED_TABLE5
    csv = (tmp_path / "report" / "tables" / "table5_iterations.csv").read_text().splitlines()
    assert csv[0] == "Source,Number of iterations,Data,PQ,PQ_dagger,RQ,SQ,mIoU"
    assert csv[-1] == 'ours,4,"synthetic world, seq 08",51.23,51.23,51.23,51.23,62.50'
    tex = (tmp_path / "report" / "tables" / "table5_iterations.tex").read_text()
    assert r"\textbf{ours} & \textbf{4} & synthetic world, seq 08 & 51.2 &" in tex
    assert tex.count(r"\midrule") == 2  # after the header and between paper and ours


def test_main_tables_group_by_dataset_and_split(tmp_path):
    runs = load_runs(
        [
            _run(tmp_path, "val", _scores(0.5), {"dataset": "semantickitti", "split": "val"}),
            _run(tmp_path, "test", _scores(0.5), {"dataset": "SemanticKITTI", "split": "test"}),
            _run(tmp_path, "nus", _scores(0.5), {"dataset": "nuscenes"}),
            _run(tmp_path, "toy", _scores(0.5), {"dataset": "toy"}),
            _run(tmp_path, "bare", _scores(0.5)),
        ]
    )
    tables = {t.name: t for t in main_tables(runs)}
    assert list(tables) == [
        "table1_semantickitti_val",
        "table2_semantickitti_test",
        "table3_nuscenes_val",
        "table_main_other",
    ]
    t1 = tables["table1_semantickitti_val"].frame
    assert list(t1["Source"]) == ["paper"] * 4 + ["ours"]
    assert t1.iloc[-1]["Method"] == "val" and t1.iloc[-1]["Data"] == "semantickitti val"
    other = tables["table_main_other"].frame
    assert list(other["Method"]) == ["toy", "bare"]
    assert other.iloc[1]["Data"] == "unspecified data"
    assert (other["Source"] == "ours").all()


def test_missing_metrics_print_as_dash(tmp_path):
    scores = {"all": {"PQ": 0.5, "SQ": 0.8, "RQ": 0.625}}
    run = load_run(_run(tmp_path, "r", scores, {"dataset": "semantickitti"}))
    md = to_markdown(main_tables([run])[0])
    assert md.splitlines()[-3] == (
        "| **ours** | **r** | semantickitti | 50.0 | - | 62.5 | 80.0 | - | - | - | - | - | - | - | - |"
    )


def test_per_class_tables_copy_values_and_match_names(tmp_path):
    classes = {"car": {"PQ": 0.9, "SQ": 0.9, "RQ": 1.0, "IoU": 0.8}}
    classes["traffic sign"] = {"PQ": 0.25, "SQ": 0.5, "RQ": 0.5, "IoU": 0.3}
    # overall PQ deliberately not the class mean: the report copies, never recomputes
    run = load_run(
        _run(tmp_path, "r", _scores(0.123, classes=classes), {"dataset": "semantickitti"})
    )
    tables = {t.name: t for t in per_class_tables([run])}
    assert list(tables) == ["table6_per_class_pq", "table7_per_class_rq", "table8_per_class_sq"]
    ours = tables["table6_per_class_pq"].frame.iloc[-1]
    assert ours["PQ"] == pytest.approx(12.3) and ours["car"] == pytest.approx(90.0)
    assert ours["traffic-sign"] == pytest.approx(25.0) and np.isnan(ours["truck"])
    assert len(tables["table7_per_class_rq"].frame) == 4 + 1


def test_per_class_other_dataset_has_no_paper_rows(tmp_path):
    classes = {"barrier": {"PQ": 0.4, "SQ": 0.8, "RQ": 0.5, "IoU": 0.6}}
    run = load_run(_run(tmp_path, "n", _scores(0.4, classes=classes), {"dataset": "nuscenes"}))
    tables = per_class_tables([run])
    assert [t.name for t in tables] == [
        "table6_per_class_pq_nuscenes",
        "table7_per_class_rq_nuscenes",
        "table8_per_class_sq_nuscenes",
    ]
    assert list(tables[0].frame.columns) == ["Source", "Method", "Data", "PQ", "barrier"]


def test_bandwidth_table_rows_sorted_and_spelled_like_the_paper(tmp_path):
    runs = load_runs(
        [
            _run(tmp_path, "b", _scores(0.5), {"bandwidths": [0.2, 2.1, 4]}),
            _run(tmp_path, "a", _scores(0.5), {"bandwidths": [0.2, 1.1, 2.0]}),
            _run(tmp_path, "c", _scores(0.5)),
        ]
    )
    frame = bandwidth_table(runs).frame
    assert list(frame["Bandwidth candidates (m)"])[-2:] == ["0.2, 1.1, 2.0", "0.2, 2.1, 4.0"]
    assert format_bandwidths([0.25, 1.7]) == "0.25, 1.7"
    assert iterations_table(runs) is None


def test_range_table_accepts_both_by_range_forms(tmp_path):
    nested = [{"range": [0, 10], "all": {"PQ": 0.6}}, {"range": [10, None], "all": {"PQ": 0.4}}]
    flat_text = '{"all": {"PQ": 0.5, "SQ": 0.5, "RQ": 1.0}, "by_range": [{"range": [0, 10], '
    flat_text += '"points": 120, "PQ": 0.7}, {"range": [10, Infinity], "points": 3, "PQ": 0.2}]}'
    d = tmp_path / "flat"
    d.mkdir()
    (d / "scores.json").write_text(flat_text)
    runs = load_runs([_run(tmp_path, "nested", _scores(0.5, by_range=nested)), d])
    frame = range_table(runs).frame
    assert list(frame.columns)[3:] == ["0-10 m", ">=10 m"]
    np.testing.assert_allclose(frame[["0-10 m", ">=10 m"]].to_numpy(), [[60, 40], [70, 20]])


def test_latex_escapes_and_csv_round_trip(tmp_path):
    run = load_run(_run(tmp_path, "r", _scores(0.5), {"method": "A_B & 50%", "dataset": "kitti"}))
    table = main_tables([run])[0]
    assert r"A\_B \& 50\%" in to_latex(table)
    assert r"PQ$^\dagger$" in to_latex(table)
    lines = to_csv(table).splitlines()
    assert lines[0].startswith("Source,Method,Data,PQ,PQ_dagger,RQ,SQ,PQ_th")
    assert lines[1].startswith("ours,A_B & 50%,kitti,50.00,50.00")


def test_run_meta_round_trip_and_rejects_unknown_keys(tmp_path):
    raw = {
        "method": "DS-Net",
        "dataset": "semantickitti",
        "split": "val",
        "data": "synthetic",
        "notes": "n",
        "command": "panoptic-bench eval x",
        "bandwidths": [0.2, 1.7, 3.2],
        "iterations": 4,
        "ablation": {"clustering": "DS"},
    }
    assert RunMeta.from_dict(raw).to_dict() == raw
    assert RunMeta.from_dict({}).to_dict() == {}
    with pytest.raises(InputError, match="unknown key"):
        RunMeta.from_dict({"methd": "x"}, tmp_path / "run.json")
    with pytest.raises(InputError, match="iterations"):
        RunMeta.from_dict({"iterations": "4"})
    with pytest.raises(InputError, match="ablation"):
        RunMeta.from_dict({"ablation": {"figure": "x"}})


@pytest.mark.parametrize(
    ("files", "culprit", "message"),
    [
        ({}, "scores.json", "no scores.json"),
        ({"scores.json": "{not json"}, "scores.json", "malformed JSON"),
        ({"scores.json": "[1, 2]"}, "scores.json", "'all'"),
        ({"scores.json": '{"all": {"PQ": 55.0, "SQ": 0.8, "RQ": 0.7}}'}, "scores.json", "fraction"),
        ({"scores.json": '{"all": {"PQ": 0.5}}'}, "scores.json", "lacks"),
        (
            {"scores.json": '{"all": {"PQ": 0.5, "SQ": 0.5, "RQ": 1}}', "run.json": "{"},
            "run.json",
            "malformed JSON",
        ),
        (
            {"scores.json": '{"all": {"PQ": 0.5, "SQ": 0.5, "RQ": 1}, "by_range": [{"r": 1}]}'},
            "scores.json",
            "by_range",
        ),
    ],
)
def test_bad_input_names_the_file(tmp_path, files, culprit, message):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    for name, text in files.items():
        (run_dir / name).write_text(text)
    with pytest.raises(InputError, match=message) as info:
        build_report([run_dir], tmp_path / "out")
    assert info.value.path == run_dir / culprit


def test_cli_report(tmp_path, capsys):
    run = _run(tmp_path, "dsnet", _scores(0.5), {"dataset": "semantickitti", "iterations": 4})
    out = tmp_path / "rep"
    assert main(["report", "--results", str(run), "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str((out / "index.md").resolve())
    index = (out / "index.md").read_text()
    assert f"```bash\n{report_command([str(run)], str(out))}\n```" in index
    assert main(["report", "--results", str(tmp_path / "nope"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope" in err and "Traceback" not in err


def test_table_builders_return_nothing_for_no_runs():
    assert build_tables([]) == []
    with pytest.raises(InputError, match="no result"):
        build_report([], "unused")
