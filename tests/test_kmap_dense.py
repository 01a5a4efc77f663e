"""The dense-volume kernel maps (CPU) equal the sorted-key maps pair for pair, in the same order."""

from __future__ import annotations

import pytest
import torch

from panoptic_bench.dsnet.sparse import SparseTensor, kmap, kmap_dense

SHAPE = (9, 7, 6)


def random_tensor(seed: int, shape=SHAPE, batch: int = 2, density: float = 0.3) -> SparseTensor:
    g = torch.Generator().manual_seed(seed)
    occ = torch.rand((batch, *shape), generator=g) < density
    coords = torch.nonzero(occ).to(torch.int32)
    coords = coords[torch.randperm(coords.shape[0], generator=g)]  # unsorted on purpose
    return SparseTensor(torch.zeros(len(coords), 1), coords, shape)


def both(fn, x: SparseTensor, monkeypatch):
    """``fn`` on a fresh cache through the dense path, then through the sorted-key path."""
    dense = fn(SparseTensor(x.features, x.coords, x.spatial_shape))
    with monkeypatch.context() as m:
        m.setattr(kmap_dense, "MAX_CELLS", 0)
        fresh = SparseTensor(x.features, x.coords, x.spatial_shape)
        ref = fn(fresh)
        assert not any(k[0] == "dense" for k in fresh.cache)  # really the other path
    return dense, ref


def assert_same_map(a: kmap.KernelMap, b: kmap.KernelMap) -> None:
    assert a.splits == b.splits and a.identity == b.identity and a.n_out == b.n_out
    assert torch.equal(a.in_idx, b.in_idx) and torch.equal(a.out_idx, b.out_idx)
    assert a.in_idx.dtype == b.in_idx.dtype == torch.int64


@pytest.mark.parametrize("kernel", [(3, 3, 3), (1, 3, 3), (3, 1, 3), (3, 1, 1), (5, 3, 1)])
@pytest.mark.parametrize("seed", [0, 1])
def test_submanifold_maps_equal(kernel, seed, monkeypatch):
    x = random_tensor(seed)
    dense, ref = both(lambda t: kmap.submanifold_map(t, kernel), x, monkeypatch)
    assert_same_map(dense, ref)
    assert dense.in_idx.numel() > 0


def test_shared_offsets_keep_the_same_order(monkeypatch):
    """Kernels sharing one cache reuse (and swap) earlier offsets' pairs: same order either way."""
    kernels = [(1, 3, 3), (3, 3, 3), (3, 1, 3), (3, 1, 1)]
    dense, ref = both(
        lambda t: [kmap.submanifold_map(t, k) for k in kernels], random_tensor(4), monkeypatch
    )
    for a, b in zip(dense, ref):
        assert_same_map(a, b)


@pytest.mark.parametrize(
    "kernel,stride,padding",
    [
        ((3, 3, 3), (2, 2, 2), (1, 1, 1)),
        ((3, 3, 3), (2, 2, 1), (1, 1, 1)),
        ((2, 2, 2), (2, 2, 2), (0, 0, 0)),
        ((3, 1, 3), (3, 1, 2), (0, 0, 1)),
    ],
)
def test_strided_maps_equal(kernel, stride, padding, monkeypatch):
    x = random_tensor(3)
    dense, ref = both(lambda t: kmap.downsample_map(t, kernel, stride, padding), x, monkeypatch)
    assert torch.equal(dense.out_coords, ref.out_coords)
    assert dense.out_shape == ref.out_shape
    assert_same_map(dense.kmap, ref.kmap)


def test_chain_uses_the_output_volume(monkeypatch):
    """Submanifold maps on a strided conv's output sites: the cached output volume, same map."""

    def chain(t: SparseTensor):
        entry = kmap.downsample_map(t, (3, 3, 3), (2, 2, 2), (1, 1, 1))
        down = SparseTensor(
            torch.zeros(len(entry.out_coords), 1),
            entry.out_coords,
            entry.out_shape,
            (2, 2, 2),
            t.cache,
        )
        return kmap.submanifold_map(down, (3, 3, 3)), t.cache

    (dense, cache), (ref, _) = both(chain, random_tensor(5, density=0.5), monkeypatch)
    assert ("dense", (2, 2, 2)) in cache
    assert_same_map(dense, ref)


def test_large_grids_fall_back(monkeypatch):
    x = random_tensor(2)
    monkeypatch.setattr(kmap_dense, "MAX_CELLS", 2 * 9 * 7 * 6 - 1)  # one cell too few
    kmap.submanifold_map(x, (3, 3, 3))
    assert not any(k[0] == "dense" for k in x.cache)
    assert not kmap_dense.usable(x.coords, 0, SHAPE)  # an empty batch never


def test_real_scan_maps_equal(monkeypatch):
    """The official grid (480 x 360 x 32) on a real scan: every pair equal."""
    from pathlib import Path

    from panoptic_bench.dsnet.checkpoint import build_grid
    from panoptic_bench.dsnet.config import load_config
    from panoptic_bench.dsnet.data.datasets import SemanticKittiDataset
    from panoptic_bench.dsnet.model.voxelize import collate

    root = Path(__file__).resolve().parents[2] / "shared" / "data" / "semantickitti"
    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "dsnet_semantickitti.yaml")
    s = SemanticKittiDataset(root, sequences=["00"]).load(0)
    scan = torch.cat([torch.from_numpy(s.xyz), torch.from_numpy(s.remission)[:, None]], 1).numpy()
    batch = collate([scan], build_grid(cfg), torch.device("cpu"))
    x = SparseTensor(
        torch.zeros(len(batch.voxel_coords), 1), batch.voxel_coords, batch.spatial_shape
    )
    assert x.coords.dtype == torch.int32
    for kernel in [(3, 3, 3), (1, 3, 3), (3, 1, 3)]:
        dense, ref = both(lambda t, k=kernel: kmap.submanifold_map(t, k), x, monkeypatch)
        assert_same_map(dense, ref)
    dense, ref = both(
        lambda t: kmap.downsample_map(t, (3, 3, 3), (2, 2, 2), (1, 1, 1)), x, monkeypatch
    )
    assert torch.equal(dense.out_coords, ref.out_coords)
    assert_same_map(dense.kmap, ref.kmap)


def test_sites_outside_the_grid_take_the_sorted_path(monkeypatch):
    """A site outside the grid (or a negative batch index) never indexes the volume."""
    x = random_tensor(6)
    coords = x.coords.clone()
    coords[0, 1] = SHAPE[0]  # one past the end
    coords[1, 0] = -1
    bad = SparseTensor(x.features, coords, SHAPE)
    dense, ref = both(lambda t: kmap.submanifold_map(t, (3, 3, 3)), bad, monkeypatch)
    assert_same_map(dense, ref)
    fresh = SparseTensor(x.features, coords, SHAPE)
    kmap.submanifold_map(fresh, (3, 3, 3))
    assert fresh.cache[("dense", (1, 1, 1))][1] is None  # refused once, remembered
    down, ref = both(
        lambda t: kmap.downsample_map(t, (3, 3, 3), (2, 2, 2), (1, 1, 1)), bad, monkeypatch
    )
    assert torch.equal(down.out_coords, ref.out_coords)
    assert_same_map(down.kmap, ref.kmap)
