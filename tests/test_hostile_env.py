"""Hostile environment, classes 7 and 8: closed stdout, full disks and Ctrl-C.

A closed pipe (``| head``) or a closed stdout ends a command quietly. A disk that fills up is a
user error: one line, exit 2, nothing half-written. The full disk is real: the commands run in a
child process whose file-size limit (``RLIMIT_FSIZE``, no root needed) makes the kernel fail
the first large write with ``EFBIG``, exactly where ``ENOSPC`` would strike. Ctrl-C in the
middle of writing (simulated at the second file) leaves nothing behind and exits 130.
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from hostile_world import NU_VERSION, digest, listing, run

REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-c", "import sys; from panoptic_bench.cli import main; sys.exit(main())"]
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


def _cli(argv, *, limit: int | None = None, **kw) -> subprocess.CompletedProcess:
    def child():  # pragma: no cover - runs in the child
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of a signal
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.run([*CLI, *map(str, argv)], env=ENV, cwd=REPO, text=True,
                          preexec_fn=child if limit else None, **kw)  # fmt: skip


def _eval(k, out):
    return ["eval", "semantickitti", "--dataset", k["data"], "--predictions", k["pred"],
            "--sequences", "08", "--output", out]  # fmt: skip


def test_closed_pipe_ends_quietly(hostile_kitti, tmp_path):
    proc = subprocess.Popen([*CLI, *map(str, _eval(hostile_kitti, tmp_path / "out"))], env=ENV,
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    proc.stdout.close()  # the reader is gone before the table is printed
    err = proc.stderr.read()
    assert proc.wait() == 141, err
    assert "Traceback" not in err and "Exception ignored" not in err
    assert (tmp_path / "out/scores.json").is_file()  # the results were written first


def test_closed_stdout_is_not_an_error(hostile_kitti, tmp_path):
    shell = subprocess.run(["bash", "-c", " ".join(f"'{a}'" for a in
                            [*CLI, *map(str, _eval(hostile_kitti, tmp_path / "out2"))]) + " >&-"],
                           env=ENV, cwd=REPO, capture_output=True, text=True)  # fmt: skip
    assert shell.returncode == 0, shell.stderr
    assert "Traceback" not in shell.stderr
    assert (tmp_path / "out2/scores.json").is_file()


def _full_disk_commands(k, n, out):
    ck = REPO / "panoptic_bench/checkpoints/dsnet_synthetic.pt"
    return {
        "cluster": ["cluster", "semantickitti", "--dataset", k["data"], "--centers", k["centers"],
                    "--method", "bfs", "--output", out],
        "eval": _eval(k, out),
        "remap": ["semantickitti", "remap", "--input", k["data"], "--output", out],
        "centers": ["centers", "simulate", "--dataset", k["data"], "--output", out],
        "make-labels": ["nuscenes", "make-labels", "--dataroot", n["dataroot"], "--version",
                        NU_VERSION, "--out-dir", out],
        "eval nuscenes": ["eval", "nuscenes", "--dataroot", n["dataroot"], "--version",
                          NU_VERSION, "--result-path", n["res"], "--eval-set", "mini_val",
                          "--output", out],
        "synth": ["synth", "semantickitti", "--out", out, "--sequences", "00:1"],
        "synth nuscenes": ["synth", "nuscenes", "--out", out, "--scenes", "2", "--samples", "1"],
        "report": ["report", "--results", REPO / "reports/real-scans-3/runs/real-bfs", "--out", out],
        "checkpoint export": ["checkpoint", "export", ck, "--out", out.with_suffix(".pt")],
        "infer": ["infer", "--checkpoint", ck, "--data", k["data"], "--sequences", "08", "--out",
                  out, "--no-progress"],
    }  # fmt: skip


FULL_DISK = ["cluster", "eval", "remap", "centers", "make-labels", "eval nuscenes", "synth",
             "synth nuscenes", "report", "checkpoint export", "infer"]  # fmt: skip


@pytest.mark.parametrize("name", FULL_DISK)
def test_full_disk_is_one_line_and_leaves_nothing(name, hostile_kitti, hostile_nuscenes, tmp_path):
    parent = tmp_path / "o"
    parent.mkdir()
    argv = _full_disk_commands(hostile_kitti, hostile_nuscenes, parent / "out")[name]
    inputs = [hostile_kitti["root"], hostile_nuscenes["dataroot"], hostile_nuscenes["res"]]
    before = [digest(p) for p in inputs]
    res = _cli(argv, limit=1500, capture_output=True)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and "Exception ignored" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("panoptic-bench")]
    assert len(lines) == 1 and ("no space" in lines[0] or "too large" in lines[0]), res.stderr
    assert listing(parent) == [], listing(parent)
    assert [digest(p) for p in inputs] == before


def _interrupt_on_second(monkeypatch, module, name):
    calls = []
    original = getattr(module, name)

    def fake(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, fake)


@pytest.mark.parametrize("name", ["cluster", "centers", "remap", "synth", "synth nuscenes"])
def test_ctrl_c_while_writing_leaves_nothing(name, hostile_kitti, hostile_nuscenes, tmp_path,
                                             monkeypatch, capsys):  # fmt: skip
    parent = tmp_path / "o"
    parent.mkdir()
    argv = _full_disk_commands(hostile_kitti, hostile_nuscenes, parent / "out")[name]
    if name == "synth":
        argv[argv.index("00:1")] = "00:2"
    _interrupt_on_second(monkeypatch, os, "fsync")  # every atomic write ends with an fsync
    status, _, err = run(argv, capsys)
    assert status == 130 and "interrupted" in err and "Traceback" not in err
    assert listing(parent) == []


def test_ctrl_c_inside_make_labels_leaves_nothing(hostile_nuscenes, tmp_path, monkeypatch, capsys):
    import panoptic_bench.datasets.nuscenes_panoptic as labels

    parent = tmp_path / "o"
    parent.mkdir()
    _interrupt_on_second(monkeypatch, labels.np, "savez_compressed")
    argv = ["nuscenes", "make-labels", "--dataroot", hostile_nuscenes["dataroot"], "--version",
            NU_VERSION, "--out-dir", parent / "out"]  # fmt: skip
    status, _, err = run(argv, capsys)
    assert status == 130 and "Traceback" not in err
    assert listing(parent) == []
