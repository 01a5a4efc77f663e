"""Hostile input, classes 1, 3, 4 and 9: outputs are all-or-nothing, never overwrite silently,
never touch an input, and get ordinary file permissions.

Every command that writes a tree is run on inputs whose *last* scan is broken (the first scan
would already have been written by a per-scan writer): the output location must stay exactly as
it was. Non-empty outputs are refused without ``--overwrite``; outputs inside or equal to an input
are refused always.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hostile_world import NU_VERSION, digest, listing, refused, run, umask_mode

REPO = Path(__file__).resolve().parents[1]
CHECKPOINT = REPO / "panoptic_bench/checkpoints/dsnet_synthetic.pt"
CONFIG = REPO / "configs/dsnet_synthetic_cpu.yaml"


@pytest.fixture
def kw(hostile_kitti, tmp_path) -> dict:
    """A private copy of the tiny SemanticKITTI world (to corrupt), and an output parent."""
    root = tmp_path / "in"
    shutil.copytree(hostile_kitti["root"], root)
    world = {k: root / Path(v).relative_to(hostile_kitti["root"]) for k, v in hostile_kitti.items()}
    world["parent"] = tmp_path / "o"
    world["parent"].mkdir()
    world["out"] = world["parent"] / "out"
    return world


def _truncate(path: Path) -> str:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2 + 1])
    return path.name


def _cluster(w, *extra):
    return ["cluster", "semantickitti", "--dataset", w["data"], "--centers", w["centers"],
            "--method", "bfs", "--output", w["out"], *extra]  # fmt: skip


def _eval(w, *extra):
    return ["eval", "semantickitti", "--dataset", w["data"], "--predictions", w["pred"],
            "--sequences", "08", "--output", w["out"], *extra]  # fmt: skip


def _compare(w, *extra):
    """``eval compare`` of two eval outputs made beside the watched parent."""
    import contextlib
    import io

    from panoptic_bench.cli import main

    runs = w["parent"].parent / "compare_inputs"
    for name in ("a", "b"):
        if not (runs / name / "per_scan.npz").is_file():
            argv = [str(a) for a in _eval(w)[:-1]] + [str(runs / name)]
            with contextlib.redirect_stdout(io.StringIO()):
                assert main(argv) == 0
    return ["eval", "compare", runs / "a", runs / "b", "--bootstrap", "50",
            "--output", w["out"], *extra]  # fmt: skip


def _merge(w, *extra):
    return ["box-merge", "semantickitti", "--dataset", w["data"], "--semantic", w["pred"],
            "--boxes", w["boxes"], "--output", w["out"], *extra]  # fmt: skip


def _centers(w, *extra):
    return ["centers", "simulate", "--dataset", w["data"], "--output", w["out"], *extra]


def _sim_boxes(w, *extra):
    return ["box-merge", "simulate-boxes", "--dataset", w["data"], "--output", w["out"], *extra]


def _remap(w, *extra):
    return ["semantickitti", "remap", "--input", w["data"], "--output", w["out"], *extra]


def _infer(w, *extra):
    return ["infer", "--checkpoint", CHECKPOINT, "--data", w["data"], "--sequences", "08",
            "--out", w["out"], "--no-progress", *extra]  # fmt: skip


CENTRE_LAST = "centers/sequences/08/centers/000001.npz"


def _nan_centres(w):
    path = w["root"] / CENTRE_LAST
    with np.load(path) as z:
        arrays = dict(z)
    arrays["offset"][3] = np.nan
    np.savez(path, **arrays)
    return path.name


def _bad_boxes_line(w):
    path = w["root"] / "boxes/sequences/08/boxes/000001.txt"
    path.write_text(path.read_text() + "1.0 2.0 3.0\n")
    return path.name


def _missing_boxes(w):
    path = w["root"] / "boxes/sequences/08/boxes/000001.txt"
    path.unlink()
    return path.name


PARTIAL = [
    ("cluster: truncated last centres", _cluster, lambda w: _truncate(w["root"] / CENTRE_LAST)),
    ("cluster: NaN in last centres", _cluster, _nan_centres),
    ("box-merge: bad line in last boxes", _merge, _bad_boxes_line),
    ("box-merge: last boxes file missing", _merge, _missing_boxes),
    ("box-merge: truncated last semantic prediction", _merge,
     lambda w: _truncate(w["pred"] / "sequences/08/predictions/000001.label")),
    ("centers: truncated last label", _centers,
     lambda w: _truncate(w["data"] / "sequences/08/labels/000001.label")),
    ("simulate-boxes: truncated last label", _sim_boxes,
     lambda w: _truncate(w["data"] / "sequences/08/labels/000001.label")),
    ("eval: truncated last prediction", _eval,
     lambda w: _truncate(w["pred"] / "sequences/08/predictions/000001.label")),
    ("remap: truncated last label", _remap,
     lambda w: _truncate(w["data"] / "sequences/08/labels/000001.label")),
    ("infer: truncated last scan", _infer,
     lambda w: _truncate(w["data"] / "sequences/08/velodyne/000001.bin")),
]  # fmt: skip


@pytest.mark.parametrize(("name", "command", "corrupt"), PARTIAL, ids=[c[0] for c in PARTIAL])
def test_broken_last_scan_leaves_no_output(name, command, corrupt, kw, capsys):
    named = corrupt(kw)
    refused(command(kw), capsys, names=[named], inputs=[kw["root"]], watch=[kw["parent"]])


WRITERS = {
    "cluster": _cluster,
    "eval": _eval,
    "eval compare": _compare,
    "box-merge": _merge,
    "centers": _centers,
    "simulate-boxes": _sim_boxes,
    "remap": _remap,
}


@pytest.mark.parametrize("command", WRITERS.values(), ids=WRITERS.keys())
def test_non_empty_output_refused_without_overwrite(command, kw, capsys):
    kw["out"].mkdir()
    (kw["out"] / "keep.txt").write_text("unrelated\n")
    refused(command(kw), capsys, names=["--overwrite", str(kw["out"])], inputs=[kw["root"]],
            watch=[kw["parent"]])  # fmt: skip
    # with --overwrite: the command's files replace their namesakes, other files stay
    status, _, err = run(command(kw, "--overwrite"), capsys)
    assert status == 0, err
    assert (kw["out"] / "keep.txt").read_text() == "unrelated\n"
    assert [p for p in listing(kw["parent"]) if p.startswith(".")] == []  # no temp left


@pytest.mark.parametrize("umask", [0o022, 0o002])
def test_outputs_get_ordinary_permissions(umask, kw, capsys):
    """Files 0o666 and directories 0o777 minus the umask (not mkstemp's private 0o600)."""
    import os

    old = os.umask(umask)
    try:
        for i, command in enumerate((_cluster, _eval, _centers)):
            kw["out"] = kw["parent"] / f"out{i}"
            assert run(command(kw), capsys)[0] == 0
            paths = [p for p in kw["out"].rglob("*")] + [kw["out"]]
            assert paths
            for p in paths:
                want = umask_mode(0o777 if p.is_dir() else 0o666)
                assert p.stat().st_mode & 0o777 == want, (p, oct(p.stat().st_mode))
    finally:
        os.umask(old)


def test_output_inside_or_equal_to_an_input_refused(kw, capsys):
    cases = [
        (_cluster(kw)[:-2] + ["--output", kw["centers"]], "inside the input tree"),
        (_cluster(kw)[:-2] + ["--output", kw["centers"] / "sub"], "inside the input tree"),
        (_eval(kw)[:-2] + ["--output", kw["pred"] / "scores"], "inside the input tree"),
        (_compare(kw)[:-2] + ["--output", _compare(kw)[2] / "cmp"], "inside the input tree"),
        (_remap(kw)[:-2] + ["--output", kw["data"] / "x"], "inside the input tree"),
        (["train", "--config", CONFIG, "--data", kw["data"], "--out", kw["data"]],
         "inside the input tree"),
        (["train", "--config", CONFIG, "--data", kw["data"], "--out", kw["data"] / "run"],
         "inside the input tree"),
        (["ablate", "--checkpoint", CHECKPOINT, "--data", kw["data"], "--out",
          kw["data"] / "abl"], "inside the input tree"),
        (["demo", "--real-scans", kw["data"], "--out", kw["data"] / "report"],
         "inside the input tree"),
    ]  # fmt: skip
    for argv, words in cases:
        refused(argv, capsys, names=[words], inputs=[kw["root"]], watch=[kw["parent"]])


def test_checkpoint_export_never_overwrites(tmp_path, capsys):
    src = tmp_path / "ck.pt"
    shutil.copyfile(CHECKPOINT, src)
    link = tmp_path / "same.pt"
    link.hardlink_to(src)
    for out, words in ((src, "is the input"), (link, "is the input")):
        refused(["checkpoint", "export", src, "--out", out], capsys, names=[words],
                inputs=[src], watch=[tmp_path])  # fmt: skip
    other = tmp_path / "other.pt"
    other.write_bytes(b"mine")
    refused(["checkpoint", "export", src, "--out", other], capsys, names=["--overwrite"],
            inputs=[src, other], watch=[tmp_path])  # fmt: skip


def test_nuscenes_outputs_never_overwrite_or_write_into_the_dataroot(hostile_nuscenes, tmp_path,
                                                                    capsys):  # fmt: skip
    nus = hostile_nuscenes
    root = nus["dataroot"]
    labels = ["nuscenes", "make-labels", "--dataroot", root, "--version", NU_VERSION]
    refused([*labels, "--out-dir", root / "lidarseg"], capsys, names=["--out-dir", "inside"],
            inputs=[root], watch=[root])  # fmt: skip
    refused([*labels, "--out-dir", root], capsys, names=["--overwrite"], inputs=[root],
            watch=[root])  # fmt: skip
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    ev = ["eval", "nuscenes", "--dataroot", root, "--version", NU_VERSION, "--result-path",
          nus["res"], "--eval-set", "mini_val", "--output", out]  # fmt: skip
    refused(ev, capsys, names=["--overwrite"], inputs=[root, nus["res"]], watch=[tmp_path])
    cl = ["cluster", "nuscenes", "--dataset", root, "--version", NU_VERSION, "--eval-set",
          "mini_val", "--centers", nus["centers"], "--method", "bfs", "--output", out]  # fmt: skip
    refused(cl, capsys, names=["--overwrite"], inputs=[root, nus["centers"]], watch=[tmp_path])
    sub = tmp_path / "sub.json"
    sub.write_text("{}")
    sim = ["box-merge", "simulate-nuscenes", "--dataset", root, "--version", NU_VERSION,
           "--eval-set", "mini_val", "--output", sub]  # fmt: skip
    refused(sim, capsys, names=["--overwrite"], inputs=[root, sub], watch=[tmp_path])


def test_nuscenes_bad_last_centres_leave_no_output(hostile_nuscenes, tmp_path, capsys):
    nus = hostile_nuscenes
    centers = tmp_path / "centers"
    shutil.copytree(nus["centers"], centers)
    last = sorted((centers / "centers").glob("*.npz"))[-1]
    with np.load(last) as z:
        arrays = dict(z)
    arrays["offset"][0] = np.inf
    np.savez(last, **arrays)
    before = digest(nus["dataroot"])
    cl = ["cluster", "nuscenes", "--dataset", nus["dataroot"], "--version", NU_VERSION,
          "--eval-set", "mini_val", "--centers", centers, "--method", "bfs", "--output",
          tmp_path / "o" / "out"]  # fmt: skip
    (tmp_path / "o").mkdir()
    refused(cl, capsys, names=[last.name], inputs=[centers], watch=[tmp_path / "o"])
    assert digest(nus["dataroot"]) == before


REFUSE_ONLY = {
    "infer": lambda w: _infer(w),
    "eval semantickitti-4d": lambda w: [
        "eval", "semantickitti-4d", "--dataset", w["data"], "--predictions", w["pred"],
        "--output", w["out"]],
    "synth semantickitti": lambda w: ["synth", "semantickitti", "--out", w["out"], "--sequences",
                                      "00:1"],
    "synth nuscenes": lambda w: ["synth", "nuscenes", "--out", w["out"]],
    "centers simulate nuscenes": lambda w: [
        "centers", "simulate", "--dataset", w["data"], "--version", NU_VERSION, "--eval-set",
        "mini_val", "--output", w["out"]],
    "box-merge nuscenes": lambda w: [
        "box-merge", "nuscenes", "--dataset", w["data"], "--version", NU_VERSION, "--eval-set",
        "mini_val", "--semantic", w["pred"], "--boxes", w["boxes"], "--output", w["out"]],
}  # fmt: skip


@pytest.mark.parametrize("name", REFUSE_ONLY, ids=list(REFUSE_ONLY))
def test_more_writers_refuse_a_non_empty_output(name, kw, capsys):
    """Refused before any input is read (the inputs here need not even fit the command)."""
    kw["out"].mkdir()
    (kw["out"] / "keep.txt").write_text("unrelated\n")
    refused(REFUSE_ONLY[name](kw), capsys, names=["--overwrite"], inputs=[kw["root"]],
            watch=[kw["parent"]])  # fmt: skip
