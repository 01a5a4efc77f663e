"""The worker policy of ``evaluation/workers.py``: free CPUs, the fallback line, lazy imports."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from panoptic_bench.evaluation import workers

REPO = Path(__file__).resolve().parents[1]


def test_free_cpus_counts_busy_cpus(monkeypatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    monkeypatch.setattr(os, "getloadavg", lambda: (3.0, 1.0, 1.0))
    free, why = workers.free_cpus()
    # the instantaneous count of /proc/loadavg can only lower the busy estimate
    assert 1 <= free <= 4 and free >= 4 - 3
    assert "4 CPUs" in why
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    assert workers.free_cpus()[0] == 4
    monkeypatch.setattr(os, "getloadavg", lambda: (9.0, 9.0, 9.0))
    monkeypatch.setattr("builtins.open", _fake_loadavg("9.00 9.00 9.00 12/300 1\n"))
    assert workers.free_cpus()[0] == 1  # never below one


def _fake_loadavg(text: str):
    import io

    real = open

    def fake(path, *args, **kwargs):
        if str(path) == "/proc/loadavg":
            return io.StringIO(text)
        return real(path, *args, **kwargs)

    return fake


def test_pool_size_falls_back_without_free_cpus(monkeypatch, capsys) -> None:
    n = 10 * workers.MIN_ITEMS_PER_WORKER
    monkeypatch.setattr(workers, "free_cpus", lambda: (1, "2 CPUs, 2.0 busy"))
    assert workers.pool_size(2, n) == 1
    err = capsys.readouterr().err
    assert "--workers 2: using 1 process" in err and "2.0 busy" in err
    monkeypatch.setattr(workers, "free_cpus", lambda: (3, "4 CPUs, 1.0 busy"))
    assert workers.pool_size(8, n) == 3
    assert workers.pool_size(2, n) == 2
    assert capsys.readouterr().err.count("\n") == 1  # only the reduced request says so


def test_pool_size_small_work_says_why(monkeypatch, capsys) -> None:
    monkeypatch.setattr(workers, "free_cpus", lambda: (8, "8 CPUs, 0.0 busy"))
    assert workers.pool_size(2, workers.MIN_ITEMS_PER_WORKER - 1) == 1
    assert "needed per worker" in capsys.readouterr().err
    assert workers.pool_size(1, 10**6) == 1
    assert capsys.readouterr().err == ""  # one worker asked: nothing to say


@pytest.mark.parametrize("n_workers", [1, 2])
def test_pool_map_keeps_order(n_workers) -> None:
    items = list(range(7))
    with workers.pool_map(_square, items, n_workers) as results:
        assert list(results) == [i * i for i in items]


def _square(i: int) -> int:
    return i * i


def test_progress_bar_disabled_off_terminal() -> None:
    bar = workers.progress_bar(3, "x", "scan", None)  # pytest captures stderr: no terminal
    bar.update()
    bar.close()
    assert type(bar).__name__ == "_NoBar"
    assert type(workers.progress_bar(3, "x", "scan", True)).__name__ == "tqdm"


HEAVY = ("torch", "pandas", "scipy", "sklearn", "numba", "matplotlib", "nuscenes", "plotly", "tqdm")


@pytest.mark.parametrize("target", ["semantickitti", "semantickitti-4d"])
def test_eval_imports_no_heavy_module(kitti_root, tmp_path, target) -> None:
    """A whole ``eval semantickitti`` (or ``-4d``) process never imports the heavy libraries."""
    pred = tmp_path / "pred" / "sequences" / "00" / "predictions"
    pred.mkdir(parents=True)
    for label in sorted((kitti_root / "sequences" / "00" / "labels").iterdir()):
        (pred / label.name).symlink_to(label)
    code = (
        "import sys\n"
        "from panoptic_bench.cli import main\n"
        f"status = main(['eval', {target!r}, '--dataset', {str(kitti_root)!r},"
        f" '--predictions', {str(tmp_path / 'pred')!r}, '--sequences', '00',"
        f" '--workers', '2', '--output', {str(tmp_path / 'out')!r}])\n"
        f"heavy = sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r}))\n"
        "print('HEAVY', status, heavy)\n"
    )
    env = dict(os.environ, OMP_NUM_THREADS="1")
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=REPO
    )
    assert out.returncode == 0, out.stderr
    assert "HEAVY 0 []" in out.stdout, out.stdout
    assert (tmp_path / "out" / "scores.json").is_file()
