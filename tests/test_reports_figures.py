"""Every report figure renders from small synthetic inputs into a non-trivial PNG."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from panoptic_bench.reports import bev, figures

THINGS = ["car", "truck", "bicycle", "person"]


def _blobs(rng: np.random.Generator, n_inst: int = 5, per: int = 60) -> np.ndarray:
    centres = rng.uniform(-15, 15, size=(n_inst, 2))
    return np.concatenate([c + rng.normal(0, 0.8, size=(per, 2)) for c in centres])


def synthetic_scan(seed: int = 0) -> dict[str, np.ndarray]:
    """A tiny BEV scene: ground ring (stuff 9), 4 cars (class 1) and a person (class 6)."""
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0, 2 * np.pi, 3000)
    rad = rng.uniform(3, 30, 3000)
    ground = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)
    objs = _blobs(rng)
    xy = np.concatenate([ground, objs])
    gt_sem = np.concatenate([np.full(3000, 9), np.repeat([1, 1, 1, 1, 6], 60)])
    gt_inst = np.concatenate([np.zeros(3000, int), np.repeat([1, 2, 3, 4, 5], 60)])
    gt_sem[:100] = 0  # some unlabelled points
    pred_inst = gt_inst.copy()
    pred_inst[3000:3060] = np.where(np.arange(60) < 30, 7, 8)  # one car over-segmented
    return {
        "xy": xy,
        "gt_sem": gt_sem,
        "gt_inst": gt_inst,
        "pred_sem": gt_sem,
        "pred_inst": pred_inst,
    }


def figure_cases(out: Path) -> dict[str, Path]:
    """Render every figure into ``out`` from synthetic inputs; returns name -> path."""
    rng = np.random.default_rng(0)
    dist = np.arange(5, 55, 10.0)
    bws = np.array([0.4, 0.8, 1.2, 1.6, 2.0])
    iters = {c: np.array([1.4, 0.9, 0.5, 0.25]) * (k + 1) / 2 for k, c in enumerate(THINGS)}
    pts = _blobs(rng, 3, 80)
    seeds = [pts[::4] * s for s in (1.0, 0.7, 0.45, 0.3)]
    bands = [np.linspace(0.2, 3.2, len(seeds[0])) * s for s in (1.0, 0.6, 0.3, 0.1)]
    scan = synthetic_scan()
    ranges = np.array([[0, 10], [10, 20], [20, 40], [40, np.inf]])
    return {
        "fig3a": figures.plot_centres_vs_distance(
            dist, {"car": 30 / dist, "person": 12 / dist}, out / "fig3a.png"
        ),
        "fig3b": figures.plot_bandwidth_vs_rq(
            bws,
            {c: np.clip(0.9 - 0.1 * k * bws, 0, 1) for k, c in enumerate(THINGS)},
            out / "fig3b.png",
        ),  # fmt: skip
        "fig4a": figures.plot_ablation(
            {
                "backbone": {"PQ": 0.55, "PQ_th": 0.57},
                "+ fusion": {"PQ": 0.56, "PQ_th": 0.585},
                "+ DS": {"PQ": 0.577, "PQ_th": 0.618},
            },
            out / "fig4a.png",
            title="Fig. 4a: framework",
        ),  # fmt: skip
        "fig5": figures.plot_bandwidth_vs_size(
            dict(zip(THINGS, [1.8, 3.0, 0.7, 0.4])),
            dict(zip(THINGS, [1.0, 1.6, 0.5, 0.3])),
            out / "fig5.png",
        ),  # fmt: skip
        "fig6": figures.plot_shift_iterations(pts, seeds, bands, out / "fig6.png"),
        "fig7": figures.plot_bandwidth_vs_iteration(iters, out / "fig7.png", lower_limit=0.2),
        "range": figures.plot_pq_vs_range(
            {"DS-Net": (ranges, [0.7, 0.6, 0.45, np.nan]), "BFS": (ranges[:3], [0.5, 0.4, 0.2])},
            out / "range.png",
        ),
        "bev": bev.plot_bev_panoptic(
            scan["xy"],
            [
                ("prediction", scan["pred_sem"], scan["pred_inst"]),
                ("ground truth", scan["gt_sem"], scan["gt_inst"]),
            ],
            thing_classes=range(1, 9),
            path=out / "bev.png",
            title="synthetic scan",
        ),  # fmt: skip
    }


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> dict[str, Path]:
    return figure_cases(tmp_path_factory.mktemp("figs"))


@pytest.mark.parametrize(
    "name", ["fig3a", "fig3b", "fig4a", "fig5", "fig6", "fig7", "range", "bev"]
)
def test_figure_is_a_non_trivial_png(rendered, name):
    path = rendered[name]
    assert path.is_file() and path.suffix == ".png"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert path.stat().st_size > 10_000
    img = mpimg.imread(path)[..., :3]
    assert img.shape[0] > 300 and img.shape[1] > 450
    assert img.std() > 0.05  # not blank
    # something coloured is drawn (not only black text on white)
    saturation = img.max(axis=2) - img.min(axis=2)
    assert (saturation > 0.3).mean() > 0.001
    assert not list(path.parent.glob(".*.tmp"))  # atomic write left no temp file


def test_png_is_deterministic(tmp_path):
    scan = synthetic_scan()
    paths = []
    for name in ("a.png", "b.png"):
        paths.append(
            bev.plot_bev_panoptic(
                scan["xy"], [("gt", scan["gt_sem"], scan["gt_inst"])], [1, 6], tmp_path / name
            )
        )
    assert paths[0].read_bytes() == paths[1].read_bytes()


def test_panoptic_colours():
    sem = np.array([0, 9, 1, 1, 1, 6, 1])
    inst = np.array([0, 0, 5, 5, 7, 5, 0])
    rgb = bev.panoptic_colours(sem, inst, thing_classes=range(1, 9))
    assert rgb.shape == (7, 3)
    assert tuple(rgb[0]) == bev.IGNORE_GREY and tuple(rgb[1]) == bev.STUFF_GREY
    assert tuple(rgb[6]) == bev.THING_NO_INSTANCE
    np.testing.assert_array_equal(rgb[2], rgb[3])  # same instance, same colour
    assert not np.array_equal(rgb[2], rgb[4])  # other id
    assert not np.array_equal(rgb[2], rgb[5])  # same id, other class: another instance


def test_bad_shapes_raise(tmp_path):
    with pytest.raises(ValueError, match="shape"):
        figures.plot_centres_vs_distance([1, 2, 3], [1, 2], tmp_path / "x.png")
    with pytest.raises(ValueError, match="panels"):
        figures.plot_shift_iterations(np.zeros((3, 2)), [np.zeros((2, 2))], [], tmp_path / "x.png")
    with pytest.raises(ValueError, match="labels"):
        bev.plot_bev_panoptic(
            np.zeros((4, 3)), [("p", np.zeros(3), np.zeros(3))], [1], tmp_path / "x.png"
        )
    assert not (tmp_path / "x.png").exists()
