"""The SemanticKITTI file-to-cells path and the numpy factorization give the kernel's exact counts.

``evaluation/semantickitti_cells.py`` scores a scan from its label codes; it must equal
``panoptic_stats`` on the same labels (itself compared with the official evaluator in
``test_metrics_devkit.py``) on every code path: small ids (the id is the index), large ids
(only those present), compressed and uncompressed pairs, and the sort fallback.
"""

from __future__ import annotations

import numpy as np
import pytest

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.evaluation import semantickitti_cells as cells
from panoptic_bench.metrics import cells as generic
from panoptic_bench.metrics.panoptic import panoptic_stats


def assert_same(a, b) -> None:
    for name in ("tp", "fp", "fn", "confusion"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(a.iou_sum, b.iou_sum)  # bit-identical sums


def perturbed(gt: np.ndarray, rng: np.random.Generator, big_ids: bool) -> np.ndarray:
    """A prediction: renumbered ids (large ones with ``big_ids``), a merge, 5 % class noise."""
    sem, inst = gt & 0xFFFF, (gt >> 16).astype(np.int64)
    ids = np.unique(inst[inst > 0])
    out = np.where(inst > 0, (inst * 977 + 40000) % 65536 if big_ids else inst * 3 + 11, 0)
    out[inst == ids[1]] = out[inst == ids[0]][0]
    noise = rng.random(len(gt)) < 0.05
    sem = sem.copy()
    sem[noise] = rng.choice([0, 1, 10, 40, 48, 70, 252], int(noise.sum()))
    return sk.make_label(sem, out)


@pytest.mark.parametrize("big_ids", [False, True])
@pytest.mark.parametrize("limits", [(1 << 16, 1 << 16), (0, 1 << 16), (1 << 16, 0)])
def test_scan_stats_equal_kernel(kitti_root, monkeypatch, big_ids, limits) -> None:
    monkeypatch.setattr(cells, "_DIRECT_CODES", limits[0])
    monkeypatch.setattr(cells, "_DENSE_PAIRS", limits[1])
    rng = np.random.default_rng(7)
    kw = {"num_classes": sk.LABELS.num_classes, "ignore": sk.LABELS.ignore_ids}
    for ref in sk.list_scans(kitti_root)[:2]:
        gt = sk.read_labels(ref.label)
        pred = perturbed(gt, rng, big_ids)
        want = panoptic_stats(sk.to_train(pred), pred, sk.to_train(gt), gt, min_points=50, **kw)
        got = cells.scan_stats(cells.label_codes(gt), cells.label_codes(pred), 50)
        assert_same(got, want)
        assert want.tp.sum() > 0 and want.fp.sum() > 0  # a case that can fail
        np.testing.assert_array_equal(
            cells.train_ids(cells.label_codes(pred)[0]), sk.to_train(pred)
        )


def test_label_codes_rejects_undefined_raw_ids() -> None:
    labels = sk.make_label(np.array([10, 40, 3]), np.array([1, 0, 0]))  # raw 3 is undefined
    assert cells.label_codes(labels) is None
    ok = cells.label_codes(labels[:2])
    assert ok is not None and len(ok[0]) == 2


@pytest.mark.parametrize("dense", [generic.DENSE_LIMIT, 1])
def test_factorize_all_ranges(monkeypatch, dense) -> None:
    monkeypatch.setattr(generic, "DENSE_LIMIT", dense)
    rng = np.random.default_rng(0)
    for dtype, top in ((np.uint16, 1 << 16), (np.uint32, 1 << 32), (np.int64, 1 << 32),
                       (np.uint64, 1 << 32)):  # fmt: skip
        x = rng.choice(rng.integers(0, top, 50, dtype=np.int64), 1000).astype(dtype)
        codes, uniq = generic.factorize(x)
        np.testing.assert_array_equal(uniq, np.unique(x.astype(np.int64)))
        np.testing.assert_array_equal(uniq[codes], x.astype(np.int64))
    codes, uniq = generic.factorize(np.zeros(0, np.uint32))
    assert codes.size == uniq.size == 0
