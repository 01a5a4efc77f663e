"""Hostile input, classes 5 and 6: corrupt files and invalid values are refused, never crash.

Each case corrupts one file of a private copy of the tiny worlds (a raw ``.npy`` where an ``.npz``
belongs, a truncated or CRC-damaged archive, a table of the wrong shape, a checkpoint with a
missing or ill-typed entry, a value out of its domain) and expects the promise: exit 2, the file
named, no traceback, no output, every input byte-identical.
"""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hostile_world import NU_VERSION, refused

REPO = Path(__file__).resolve().parents[1]
CHECKPOINT = REPO / "panoptic_bench/checkpoints/dsnet_synthetic.pt"


@pytest.fixture
def nus(hostile_nuscenes, tmp_path) -> dict:
    root = tmp_path / "in"
    shutil.copytree(hostile_nuscenes["dataroot"], root / "nus")
    shutil.copytree(hostile_nuscenes["res"], root / "res")
    return {"root": root, "dataroot": root / "nus", "res": root / "res", "parent": tmp_path / "o"}


@pytest.fixture
def kw(hostile_kitti, tmp_path) -> dict:
    root = tmp_path / "in"
    shutil.copytree(hostile_kitti["root"], root)
    world = {k: root / Path(v).relative_to(hostile_kitti["root"]) for k, v in hostile_kitti.items()}
    world["parent"] = tmp_path / "o"
    return world


def _first(folder: Path, pattern: str = "*.npz") -> Path:
    return sorted(folder.glob(pattern))[0]


def _pred(w):
    return _first(w["res"] / "panoptic/mini_val")


def _raw_npy(path: Path) -> str:
    with np.load(path) as z:
        data = z["data"]
    with open(path, "wb") as fh:
        np.save(fh, data)
    return path.name


def _truncate(path: Path) -> str:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path.name


def _crc(path: Path) -> str:
    data = bytearray(path.read_bytes())
    data[60] ^= 0xFF  # inside the deflated member
    path.write_bytes(bytes(data))
    return path.name


def _table(w, name: str, obj) -> str:
    (w["dataroot"] / NU_VERSION / f"{name}.json").write_text(json.dumps(obj))
    return f"{name}.json"


def _rows(w, name: str, change) -> str:
    path = w["dataroot"] / NU_VERSION / f"{name}.json"
    rows = json.loads(path.read_text())
    for row in rows:
        change(row)
    path.write_text(json.dumps(rows))
    return path.name


def _lidarseg_class(w, value: int) -> str:
    path = _first(w["dataroot"] / "lidarseg" / NU_VERSION, "*.bin")
    labels = np.fromfile(path, dtype=np.uint8)
    labels[0] = value
    labels.tofile(path)
    return path.name


NUS_CASES = [
    ("prediction is a raw .npy", lambda w: _raw_npy(_pred(w)), "not an .npz"),
    ("prediction zip truncated", lambda w: _truncate(_pred(w)), "corrupt or truncated"),
    ("prediction zip CRC error", lambda w: _crc(_pred(w)), "corrupt or truncated"),
    ("ground truth npz truncated",
     lambda w: _truncate(_first(w["dataroot"] / "panoptic" / NU_VERSION)), "corrupt or truncated"),
    ("sample_data.json is an object", lambda w: _table(w, "sample_data", {"a": 1}), "JSON list"),
    ("sample_data.json is numbers", lambda w: _table(w, "sample_data", [1, 2, 3]), "object"),
    ("sample_data rows without filename",
     lambda w: _rows(w, "sample_data", lambda r: r.pop("filename")), "filename"),
    ("panoptic.json numeric file names",
     lambda w: _rows(w, "panoptic", lambda r: r.update(filename=123)), "string"),
    ("lidarseg.json is [1,2,3]", lambda w: _table(w, "lidarseg", [1, 2, 3]), "object"),
]  # fmt: skip


@pytest.mark.parametrize(("name", "corrupt", "words"), NUS_CASES, ids=[c[0] for c in NUS_CASES])
def test_corrupt_nuscenes_files_in_eval(name, corrupt, words, nus, capsys):
    named = corrupt(nus)
    argv = ["eval", "nuscenes", "--dataroot", nus["dataroot"], "--version", NU_VERSION,
            "--result-path", nus["res"], "--eval-set", "mini_val", "--output",
            nus["parent"] / "out"]  # fmt: skip
    refused(argv, capsys, names=[named, words], inputs=[nus["root"]], watch=[nus["root"].parent])


@pytest.mark.parametrize(
    ("corrupt", "words"),
    [
        (lambda w: _lidarseg_class(w, 200), "lidarseg class 200"),
        (lambda w: _lidarseg_class(w, 32), "lidarseg class 32"),
        (lambda w: _table(w, "sample_data", {"a": 1}), "JSON list"),
        (lambda w: _table(w, "lidarseg", [1, 2, 3]), "object"),
    ],
    ids=["class 200 (wraps uint16)", "class 32", "sample_data object", "lidarseg numbers"],
)
def test_invalid_lidarseg_in_make_labels(corrupt, words, nus, capsys):
    named = corrupt(nus)
    nus["parent"].mkdir()
    argv = ["nuscenes", "make-labels", "--dataroot", nus["dataroot"], "--version", NU_VERSION,
            "--out-dir", nus["parent"] / "out"]  # fmt: skip
    refused(argv, capsys, names=[named, words], inputs=[nus["root"]], watch=[nus["parent"]])


def _box_line(line: str):
    def corrupt(w):
        path = w["boxes"] / "sequences/08/boxes/000000.txt"
        path.write_text(path.read_text() + line + "\n")
        return path.name

    return corrupt


def _label_value(rel: str, value: int):
    def corrupt(w):
        path = w["root"] / rel
        labels = np.fromfile(path, dtype=np.uint32)
        labels[0] = value
        labels.tofile(path)
        return path.name

    return corrupt


def _nan_point(w):
    path = w["data"] / "sequences/08/velodyne/000000.bin"
    points = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
    points[5, 0], points[6, 2] = np.nan, np.inf
    points.tofile(path)
    return path.name


def _merge(w):
    return ["box-merge", "semantickitti", "--dataset", w["data"], "--semantic", w["pred"],
            "--boxes", w["boxes"], "--output", w["parent"] / "out"]  # fmt: skip


def _eval_range(w):
    return ["eval", "semantickitti", "--dataset", w["data"], "--predictions", w["pred"],
            "--sequences", "08", "--by-range", "0,10,50", "--output", w["parent"] / "out"]  # fmt: skip


def _cluster(w):
    return ["cluster", "semantickitti", "--dataset", w["data"], "--centers", w["centers"],
            "--method", "dbscan", "--output", w["parent"] / "out"]  # fmt: skip


def _infer(w):
    return ["infer", "--checkpoint", CHECKPOINT, "--data", w["data"], "--sequences", "08",
            "--out", w["parent"] / "out", "--no-progress"]  # fmt: skip


KITTI_CASES = [
    ("box negative size", _merge, _box_line("1 2 3 -1 2 2 0 1 0.9"), "positive l, w, h"),
    ("box zero size", _merge, _box_line("1 2 3 1 0 2 0 1 0.9"), "positive l, w, h"),
    ("box NaN centre", _merge, _box_line("nan 2 3 1 2 2 0 1 0.9"), "finite"),
    ("box class superscript two", _merge, _box_line("1 2 3 1 2 2 0 ² 0.9"), "unknown class"),
    ("box class 99", _merge, _box_line("1 2 3 1 2 2 0 99 0.9"), "class id 99"),
    ("box-merge unknown raw id", _merge,
     _label_value("pred/sequences/08/predictions/000000.label", 77), "unknown raw label ids"),
    ("eval --by-range NaN ground-truth points", _eval_range, _nan_point, "NaN or infinite"),
    ("cluster scan with NaN points", _cluster, _nan_point, "NaN or infinite"),
    ("infer scan with NaN points", _infer, _nan_point, "NaN or infinite"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("name", "command", "corrupt", "words"), KITTI_CASES, ids=[c[0] for c in KITTI_CASES]
)
def test_invalid_values_in_kitti_inputs(name, command, corrupt, words, kw, capsys):
    named = corrupt(kw)
    refused(command(kw), capsys, names=[named, words], inputs=[kw["root"]],
            watch=[kw["root"].parent])  # fmt: skip


def _first_matrix(ck):
    return next(k for k, v in ck["backbone"].items() if v.ndim >= 2)


CHECKPOINT_CASES = {
    "missing stage": (lambda ck: ck.pop("stage"), "'stage'"),
    "string epoch": (lambda ck: ck.update(epoch="five"), "epoch"),
    "stage banana": (lambda ck: ck.update(stage="banana"), "banana"),
    "incomplete class map": (lambda ck: ck["class_map"].pop("thing_ids"), "thing_ids"),
    "empty state dict": (lambda ck: ck.update(backbone={}), "empty"),
    "ds stage without shift": (lambda ck: ck.update(shift=None), "shift"),
    "wrong-shape weights": (
        lambda ck: ck["backbone"].update({_first_matrix(ck): __import__("torch").zeros(3, 3)}),
        "do not fit",
    ),
    "5-class map for a 20-class head": (
        lambda ck: ck["class_map"].update(class_names=ck["class_map"]["class_names"][:5]),
        "do not fit",
    ),
    "config section 0": (lambda ck: ck["config"].update(optim=0), "mapping"),
    "config lr inf": (lambda ck: ck["config"]["optim"].update(lr=float("inf")), "optim.lr"),
}


@pytest.fixture(scope="module")
def shipped():
    import torch

    return torch.load(CHECKPOINT, map_location="cpu", weights_only=True)


@pytest.mark.parametrize("case", CHECKPOINT_CASES, ids=list(CHECKPOINT_CASES))
def test_bad_checkpoint_refused_by_infer(case, shipped, kw, capsys):
    import torch

    mutate, words = CHECKPOINT_CASES[case]
    ck = copy.deepcopy(shipped)
    mutate(ck)
    bad = kw["root"] / "bad.pt"
    torch.save(ck, bad)
    argv = _infer(kw)
    argv[argv.index(CHECKPOINT)] = bad
    refused(argv, capsys, names=["bad.pt", words], inputs=[kw["root"]], watch=[kw["root"].parent])
    if case not in ("wrong-shape weights", "5-class map for a 20-class head"):
        refused(["checkpoint", "show", bad], capsys, names=["bad.pt", words], inputs=[bad])


CONFIG_CASES = {
    "section 0": ({"optim": 0}, "optim"),
    "lr .inf": ({"optim": {"lr": float("inf")}}, "optim.lr"),
    "val_every 0": ({"optim": {"val_every": 0}}, "val_every"),
    "negative translate width": ({"augment": {"translate_std": [-0.1, 0.1, 0.1]}}, "translate_std"),
    "NaN bandwidths": ({"dynamic_shift": {"bandwidths": [float("nan"), 1.0]}}, "bandwidths"),
    "NaN loss weight": ({"loss": {"ce": float("nan")}}, "loss.ce"),
    "ds weights shorter than iterations": (
        {"loss": {"ds_iteration_weights": [1.0]}, "dynamic_shift": {"iterations": 4}},
        "ds_iteration_weights",
    ),
    "mixed int/str keys": ({"optim": {"lr": 0.1, 3: 1, "zz": 2}}, "unknown config key"),
}


@pytest.mark.parametrize("case", CONFIG_CASES, ids=list(CONFIG_CASES))
def test_bad_training_config_refused_before_the_run_directory(case, kw, capsys):
    import yaml

    mapping, words = CONFIG_CASES[case]
    cfg = kw["root"] / "bad.yaml"
    cfg.write_text(yaml.safe_dump(mapping))
    argv = ["train", "--config", cfg, "--data", kw["data"], "--out", kw["parent"] / "run",
            "--device", "cpu", "--no-progress"]  # fmt: skip
    refused(argv, capsys, names=["bad.yaml", words], inputs=[kw["root"]],
            watch=[kw["root"].parent])  # fmt: skip


@pytest.mark.parametrize("size", [[0.0, 1.0, 1.0], [-1.0, 2.0, 1.5]], ids=["zero", "negative"])
def test_nuscenes_submission_box_sizes(size, nus, hostile_nuscenes, tmp_path, capsys):
    """box-merge nuscenes: a detection box of size <= 0 is refused, naming the submission."""
    from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar
    from panoptic_bench.evaluation.nuscenes import ChallengeClasses

    reader = NuScenesLidar(nus["dataroot"], NU_VERSION)
    lut = ChallengeClasses.from_nusc(reader.nusc).lut
    seg = nus["root"] / "seg/lidarseg/mini_val"
    seg.mkdir(parents=True)
    for tok in reader.sample_data_tokens("mini_val"):
        lut[reader.load_lidarseg(tok)].astype(np.uint8).tofile(seg / f"{tok}_lidarseg.bin")
    sub = nus["root"] / "sub.json"
    sim = ["box-merge", "simulate-nuscenes", "--dataset", nus["dataroot"], "--version",
           NU_VERSION, "--eval-set", "mini_val", "--miss-rate", "0", "--output", sub]  # fmt: skip
    from hostile_world import run

    assert run(sim, capsys)[0] == 0
    data = json.loads(sub.read_text())
    first = next(t for t, boxes in data["results"].items() if boxes)
    data["results"][first][0]["size"] = size
    sub.write_text(json.dumps(data))
    argv = ["box-merge", "nuscenes", "--dataset", nus["dataroot"], "--version", NU_VERSION,
            "--eval-set", "mini_val", "--semantic", nus["root"] / "seg", "--boxes", sub,
            "--output", nus["parent"] / "out"]  # fmt: skip
    refused(argv, capsys, names=["sub.json", "sizes must be > 0"], inputs=[nus["root"]],
            watch=[nus["root"].parent])  # fmt: skip


@pytest.mark.parametrize(
    ("name", "corrupt", "words"), NUS_CASES[:3], ids=[c[0] for c in NUS_CASES[:3]]
)
def test_corrupt_predictions_in_validate_nuscenes(name, corrupt, words, nus, capsys):
    """validate nuscenes lists a corrupt archive as one problem (never a zipfile traceback)."""
    named = corrupt(nus)
    argv = ["validate", "nuscenes", "--dataroot", nus["dataroot"], "--version", NU_VERSION,
            "--result-path", nus["res"], "--eval-set", "mini_val"]  # fmt: skip
    refused(argv, capsys, names=[named, words], inputs=[nus["root"]], watch=[nus["root"].parent])


def _per_scan_pair(kw, capsys) -> tuple[Path, Path]:
    from hostile_world import run

    outs = []
    for name in ("a", "b"):
        out = kw["root"] / f"eval_{name}"
        argv = ["eval", "semantickitti", "--dataset", kw["data"], "--predictions", kw["pred"],
                "--sequences", "08", "--output", out]  # fmt: skip
        assert run(argv, capsys)[0] == 0
        outs.append(out)
    return outs[0], outs[1]


def _npz_edit(**change):
    def edit(path: Path) -> None:
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        for key, fn in change.items():
            if fn is None:
                arrays.pop(key)
            else:
                arrays[key] = fn(arrays[key])
        with open(path, "wb") as fh:
            np.savez(fh, **arrays)

    return edit


PER_SCAN_CASES = {
    "raw npy": (lambda p: np.save(open(p, "wb"), np.zeros(3)), "np.savez"),
    "truncated": (lambda p: p.write_bytes(p.read_bytes()[:100]), "per_scan.npz"),
    "missing tp": (_npz_edit(tp=None), "tp"),
    "tp wrong shape": (_npz_edit(tp=lambda a: a[:, :5]), "shape"),
    "negative fn": (_npz_edit(fn=lambda a: a - 1), "non-negative"),
    "NaN iou_sum": (_npz_edit(iou_sum=lambda a: a * np.nan), "finite"),
    "iou_sum above tp": (_npz_edit(iou_sum=lambda a: a + 5.0), "[0, tp]"),
    "thing id 99": (_npz_edit(things=lambda a: a + 98), "outside"),
}


@pytest.mark.parametrize("case", PER_SCAN_CASES, ids=list(PER_SCAN_CASES))
def test_corrupt_per_scan_counts_refused_by_compare(case, kw, capsys):
    a, b = _per_scan_pair(kw, capsys)
    corrupt, words = PER_SCAN_CASES[case]
    corrupt(b / "per_scan.npz")
    argv = ["eval", "compare", a, b, "--bootstrap", "20", "--output", kw["parent"] / "cmp"]
    refused(argv, capsys, names=["per_scan.npz", words], inputs=[kw["root"]],
            watch=[kw["root"].parent])  # fmt: skip
