"""build_report with every optional figure input, index.md links, determinism, a real scan."""

from __future__ import annotations

import json
import re
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from panoptic_bench.datasets.semantickitti import read_labels, read_scan, split_label, to_train
from panoptic_bench.errors import InputError
from panoptic_bench.reports.bev import plot_bev_panoptic
from panoptic_bench.reports.index import build_report

KITTI_THINGS = list(range(1, 9))  # SemanticKITTI learning ids of the 8 things classes


def _scores(pq: float) -> dict:
    keys = ("PQ", "PQ_dagger", "SQ", "RQ", "PQ_th", "SQ_th", "RQ_th", "PQ_st", "SQ_st", "RQ_st")
    by_range = [
        {"range": [0, 20], "all": {"PQ": pq + 0.1}},
        {"range": [20, 40], "all": {"PQ": pq}},
        {"range": [40, None], "all": {"PQ": pq - 0.2}},
    ]
    classes = {"car": {"PQ": pq, "SQ": 0.9, "RQ": pq / 0.9, "IoU": 0.7}}
    return {
        "all": {k: pq for k in keys} | {"mIoU": 0.6},
        "classes": classes,
        "by_range": by_range,
    }


def _write_run(root: Path, name: str, pq: float, meta: dict, *, extras: bool = False) -> Path:
    d = root / name
    d.mkdir(parents=True)
    (d / "scores.json").write_text(json.dumps(_scores(pq)))
    (d / "run.json").write_text(json.dumps(meta))
    if extras:
        rng = np.random.default_rng(1)
        analysis = {
            "centres_per_voxel": {"distance_m": [5, 15, 25, 35], "counts": [6.0, 3.1, 1.9, 1.2]},
            "bandwidth_rq": {
                "bandwidth_m": [0.4, 0.8, 1.2],
                "rq": {"car": [0.7, 0.9, 0.95], "person": [0.8, 0.7, 0.5]},
            },
            "learned_bandwidth": {
                "size_m": {"car": 1.8, "person": 0.4},
                "bandwidth_m": {"car": 1.1, "person": 0.3},
            },
            "bandwidth_per_iteration": {
                "bandwidth_m": {"car": [1.5, 0.8, 0.4, 0.2], "person": [0.6, 0.3, 0.2, 0.2]},
                "lower_limit": 0.2,
            },
        }
        (d / "analysis.json").write_text(json.dumps(analysis))
        pts = rng.normal(size=(200, 3)) * 2
        seeds = np.stack([pts[::5] * s for s in (1.0, 0.5, 0.2)])
        np.savez(
            d / "shift_iterations.npz", points=pts, seeds=seeds, bandwidths=rng.random((3, 40))
        )
        sem = np.where(np.arange(500) < 100, 1, 9)
        inst = np.where(sem == 1, 1 + np.arange(500) % 3, 0)
        np.savez(
            d / "bev.npz",
            xyz=rng.uniform(-20, 20, (500, 3)),
            pred_sem=sem,
            pred_inst=inst,
            gt_sem=sem,
            gt_inst=inst,
            thing_classes=np.array(KITTI_THINGS),
        )
    return d


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> tuple[Path, list[Path]]:
    root = tmp_path_factory.mktemp("runs")
    kitti = {"dataset": "semantickitti", "split": "val", "data": "synthetic world"}
    runs = [
        _write_run(
            root,
            "dsnet",
            0.6,
            kitti
            | {
                "method": "DS-Net",
                "bandwidths": [0.2, 1.7, 3.2],
                "iterations": 4,
                "command": "panoptic-bench eval semantickitti --pred preds/dsnet",
                "ablation": {
                    "framework": "+ DS",
                    "clustering": "DS",
                    "bandwidth_learning": "weights",
                },
            },
            extras=True,
        ),
        _write_run(
            root, "ms", 0.5, kitti | {"method": "Mean Shift", "ablation": {"clustering": "MS"}}
        ),
        _write_run(
            root, "bb", 0.45, kitti | {"method": "backbone", "ablation": {"framework": "bb"}}
        ),
    ]
    out = root / "report"
    build_report(runs, out)
    return out, runs


def test_every_artefact_is_written(report):
    out, _ = report
    figures = sorted(p.name for p in (out / "figures").iterdir())
    assert figures == [
        "bev_panoptic_dsnet.png",
        "fig3a_centres_vs_distance_dsnet.png",
        "fig3b_bandwidth_vs_rq_dsnet.png",
        "fig4a_framework.png",
        "fig4b_clustering.png",
        "fig4c_bandwidth_learning.png",
        "fig5_bandwidth_vs_size_dsnet.png",
        "fig6_shift_iterations_dsnet.png",
        "fig7_bandwidth_vs_iteration_dsnet.png",
        "pq_vs_range.png",
    ]
    tables = sorted(p.stem for p in (out / "tables").glob("*.md"))
    assert tables == [
        "range_pq",
        "table1_semantickitti_val",
        "table4_bandwidths",
        "table5_iterations",
        "table6_per_class_pq",
        "table7_per_class_rq",
        "table8_per_class_sq",
    ]
    for stem in tables:
        assert (out / "tables" / f"{stem}.csv").is_file() and (
            out / "tables" / f"{stem}.tex"
        ).is_file()
    for png in (out / "figures").iterdir():
        assert mpimg.imread(png).std() > 0.05


def test_index_links_resolve_and_name_commands(report):
    out, runs = report
    index = (out / "index.md").read_text()
    links = re.findall(r"\]\(([^)]+)\)", index)
    assert len(links) == 7 * 3 + 10
    for link in links:
        assert (out / link).is_file(), link
    assert "panoptic-bench eval semantickitti --pred preds/dsnet" in index
    assert (
        index.count(f"panoptic-bench report --results {runs[0]} {runs[1]} {runs[2]}") == 7 + 10 + 1
    )
    assert f"and `{runs[0] / 'analysis.json'}`" in index


def test_rebuilding_gives_identical_files(report, tmp_path):
    out, runs = report
    again = tmp_path / "again"
    build_report(
        runs,
        again,
        command=f"panoptic-bench report --results {' '.join(map(str, runs))} --out {out}",
    )
    for path in sorted(out.rglob("*")):
        if path.is_file():
            assert path.read_bytes() == (again / path.relative_to(out)).read_bytes(), path


def test_bad_figure_inputs_name_the_file(tmp_path):
    run = _write_run(tmp_path, "r", 0.5, {"method": "x"})
    (run / "analysis.json").write_text(json.dumps({"bandwidth_rq": {"bandwidth_m": [1, 2]}}))
    with pytest.raises(InputError) as info:
        build_report([run], tmp_path / "out")
    assert info.value.path == run / "analysis.json"
    (run / "analysis.json").write_text(
        json.dumps({"bandwidth_rq": {"bandwidth_m": [1, 2], "rq": {"car": [1]}}})
    )
    with pytest.raises(InputError, match="shape") as info:
        build_report([run], tmp_path / "out")
    assert info.value.path == run / "analysis.json"
    (run / "analysis.json").unlink()
    (run / "bev.npz").write_bytes(b"not an npz")
    with pytest.raises(InputError) as info:
        build_report([run], tmp_path / "out")
    assert info.value.path == run / "bev.npz"


def test_bev_of_a_real_scan(kitti_root, tmp_path):
    """A full real scan (~40k points): GT beside a prediction with instances merged per class."""
    scan = read_scan(kitti_root / "sequences" / "00" / "velodyne" / "000000.bin")
    raw, inst = split_label(
        read_labels(kitti_root / "sequences" / "00" / "labels" / "000000.label")
    )
    sem = to_train(raw)
    things = np.isin(sem, KITTI_THINGS)
    assert things.any() and len(np.unique(inst[things])) > 1
    merged = np.where(things, 1, 0)  # under-segmentation: one instance per class
    path = plot_bev_panoptic(
        scan[:, :3],
        [("all instances merged", sem, merged), ("ground truth", sem, inst)],
        KITTI_THINGS,
        tmp_path / "bev.png",
        extent=(-40, 40, -40, 40),
        title="sequences/00/000000",
    )
    img = mpimg.imread(path)[..., :3]
    left, right = img[:, : img.shape[1] // 2], img[:, img.shape[1] // 2 :]
    colours = [
        len(np.unique((half.reshape(-1, 3) * 255).astype(np.uint8), axis=0))
        for half in (left, right)
    ]
    saturated = [((h.max(axis=2) - h.min(axis=2)) > 0.3).sum() for h in (left, right)]
    assert min(saturated) > 200  # things drawn in colour on both sides
    assert colours[1] > colours[0] > 50
