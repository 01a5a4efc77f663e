"""Hostile environment, class 10: the committed HDBSCAN rows rebuild exactly on any CPU.

``hdbscan`` sorts its spanning-tree edges with numpy's default quicksort, whose order of *equal*
weights differs between the AVX-512 kernel and the scalar one; HDBSCAN of regressed centres
(full of ties) then differs between machines. ``NPY_DISABLE_CPU_FEATURES`` switches the AVX-512
kernels off, so one machine can play both: the labels, and a committed HDBSCAN table rebuilt
from the real scans, must be identical either way.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from panoptic_bench.baselines.hdbscan_tree import hdbscan_labels

REPO = Path(__file__).resolve().parents[1]
NO_AVX512 = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL"


def _tied_centres(seed: int = 0) -> np.ndarray:
    """Clumps of exactly repeated centres plus jitter rounded to 1 cm: many equal distances."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-40, 40, (40, 3))
    pts = np.repeat(centres, rng.integers(5, 120, 40), axis=0)
    moved = rng.random((len(pts), 1)) < 0.5
    pts = np.round(pts + rng.normal(0, 0.05, pts.shape) * moved, 2)
    return np.concatenate([pts, np.round(rng.uniform(-40, 40, (200, 3)), 2)])


def _python(code: str, env: dict | None = None) -> str:
    full = {**os.environ, "OMP_NUM_THREADS": "1", **(env or {})}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full,
                         cwd=REPO, check=False)  # fmt: skip
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_hdbscan_labels_do_not_depend_on_the_cpu():
    code = (
        "import sys; sys.path.insert(0, 'tests'); import numpy as np\n"
        "from test_hostile_reproducible import _tied_centres\n"
        "from panoptic_bench.baselines.hdbscan_tree import hdbscan_labels\n"
        "print(hdbscan_labels(_tied_centres(), 5).tolist())"
    )
    here = hdbscan_labels(_tied_centres(), 5)
    assert len(np.unique(here)) > 10  # a real clustering, not all noise
    no_avx512 = json.loads(_python(code, {"NPY_DISABLE_CPU_FEATURES": NO_AVX512}))
    assert here.tolist() == no_avx512


@pytest.mark.parametrize(
    ("min_cluster_size", "min_samples", "eps", "single"),
    [(5, None, 0.0, False), (10, 3, 0.0, False), (5, None, 0.5, False), (2, 1, 0.0, True)],
)
def test_equal_to_hdbscan_with_a_stable_sort(min_cluster_size, min_samples, eps, single,
                                                   monkeypatch):  # fmt: skip
    """The reference: ``hdbscan.HDBSCAN()`` itself, its argsort made stable (same tie order)."""
    import hdbscan
    import hdbscan.hdbscan_ as ref

    stable = types.SimpleNamespace(**{k: getattr(np, k) for k in dir(np) if not k.startswith("__")})
    stable.argsort = lambda a, *args, **kw: np.argsort(a, kind="stable")
    monkeypatch.setattr(ref, "np", stable)
    X = _tied_centres(1)
    want = hdbscan.HDBSCAN(
        min_cluster_size=min_cluster_size, min_samples=min_samples,
        cluster_selection_epsilon=eps, allow_single_cluster=single, core_dist_n_jobs=1,
    ).fit(X).labels_  # fmt: skip
    got = hdbscan_labels(X, min_cluster_size, min_samples, eps, single)
    assert got.tolist() == want.tolist()


def test_committed_real_scans_hdbscan_rebuilds_exactly(shared_data, tmp_path):
    """reports/real-scans-3/runs/real-hdbscan/scores.json, byte for byte, with AVX-512 off.

    The pipeline of its run.json: DS-Net regression with the checkpoint named in the DS-Net
    run's notes (one torch thread), HDBSCAN (min cluster size 5, min 50 points, fusion), eval.
    """
    committed = REPO / "reports/real-scans-3/runs"
    notes = json.loads((committed / "real-dsnet/run.json").read_text())["notes"]
    checkpoint = REPO / re.search(r"checkpoint (\S+\.pt)", notes).group(1)
    data = shared_data / "semantickitti"
    out = tmp_path
    steps = [
        ["infer", "--checkpoint", checkpoint, "--data", data, "--sequences", "00", "--threads",
         "1", "--out", out / "centres", "--no-progress"],
        ["cluster", "semantickitti", "--dataset", data, "--centers", out / "centres",
         "--sequences", "00", "--method", "hdbscan", "--min-cluster-size", "5", "--output",
         out / "pred"],
        ["eval", "semantickitti", "--dataset", data, "--predictions", out / "pred",
         "--sequences", "00", "--by-range", "0,10,20,30,40,50,80", "--output", out / "run"],
    ]  # fmt: skip
    code = "from panoptic_bench.cli import main\n" + "".join(
        f"assert main({[str(a) for a in argv]!r}) == 0\n" for argv in steps
    )
    _python(code, {"NPY_DISABLE_CPU_FEATURES": NO_AVX512})
    rebuilt = (out / "run/scores.json").read_bytes()
    assert rebuilt == (committed / "real-hdbscan/scores.json").read_bytes()
