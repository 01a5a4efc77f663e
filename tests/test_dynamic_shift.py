"""Dynamic shifting: sparse ops vs a dense reference, gradients (appendix eq. 13–17), edge cases,
FPS, loss, and clustering of blobs of very different sizes against a fixed-bandwidth mean shift."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import torch
from sklearn.metrics import adjusted_rand_score

from panoptic_bench.baselines.meanshift import MeanShift
from panoptic_bench.dsnet.config import ShiftKernel
from panoptic_bench.dsnet.model.dynamic_shift import (
    DynamicShift,
    assign_to_seeds,
    cluster_seeds,
    dynamic_shift_loss,
    flat_shift_step,
    select_seeds,
)
from panoptic_bench.dsnet.model.shift_ops import ball_sums, gaussian_kernel_means

BWS = (0.2, 1.7, 3.2)


# ---------------------------------------------------------------- dense references (tests only)
def dense_flat_means(x: np.ndarray, bandwidths) -> np.ndarray:
    """(M, l, 3): mean of the points with Σ_d (x_i − x_j)² ≤ δ² via the full M x M matrix."""
    d2 = ((x[:, None, :] - x[None, :, :]) ** 2).sum(-1)
    out = []
    for delta in bandwidths:
        k = (d2 <= delta**2).astype(np.float64)
        out.append(k @ x / k.sum(1, keepdims=True))
    return np.stack(out, axis=1)


def dense_gaussian_means(x: torch.Tensor, bw: torch.Tensor, cutoff: float | None) -> torch.Tensor:
    xd = x.detach().double()
    d2 = ((xd[:, None, :] - xd[None, :, :]) ** 2).sum(-1)
    k = torch.exp(-d2.to(bw.dtype) / (2 * bw[:, None] ** 2))
    if cutoff is not None:
        k = k * (d2 <= (cutoff * bw.detach().double()[:, None]) ** 2).to(k.dtype)
    return (k @ x.detach().to(k.dtype)) / k.sum(1, keepdim=True)


def dense_forward(module: DynamicShift, x: torch.Tensor, f: torch.Tensor) -> list[torch.Tensor]:
    out = [x]
    for mlp in module.mlps:
        if module.kernel is ShiftKernel.FLAT:
            w = torch.softmax(mlp(f), 1)
            s = torch.from_numpy(dense_flat_means(x.detach().double().numpy(), module.bandwidths))
            x = (w[..., None] * s.to(w.dtype)).sum(1)
        else:
            x = dense_gaussian_means(x, module.regressed_bandwidth(mlp(f)), module.gaussian_cutoff)
        out.append(x)
    return out


def lidar_like(rng: np.random.Generator, n: int = 1500) -> np.ndarray:
    """Strips and blobs of varying size and density, like regressed centres."""
    parts = []
    for _ in range(8):
        centre = rng.uniform(-15, 15, 3) * np.array([1, 1, 0.1])
        length = rng.choice([0.5, 2.0, 4.0])
        k = rng.integers(20, n // 4)
        along = rng.uniform(-length / 2, length / 2, (k, 1)) * rng.normal(size=(1, 3))
        parts.append(centre + along + rng.normal(scale=rng.choice([0.05, 0.3]), size=(k, 3)))
    return np.concatenate(parts)


# ---------------------------------------------------------------- sparse vs dense
BALL_CASES = {
    "lidar_like": lambda rng: lidar_like(rng),
    "far_apart_clusters": lambda rng: np.concatenate(  # empty cells between occupied ones
        [lidar_like(rng, 400), lidar_like(rng, 400) + [1e4, -3e3, 50.0]]
    ),
    "huge_extent": lambda rng: rng.uniform(-1e7, 1e7, (300, 3)),  # keys must not overflow
    "duplicates": lambda rng: np.repeat(rng.normal(size=(60, 3)), 5, axis=0),
}


@pytest.mark.parametrize("case", sorted(BALL_CASES))
@pytest.mark.parametrize("radii", [BWS, (3.2, 0.2, 1.7, 0.2), (0.5,)])
def test_ball_sums_match_dense(case, radii):
    x = BALL_CASES[case](np.random.default_rng(len(case)))
    d2 = ((x[:, None] - x[None]) ** 2).sum(-1)
    threads = numba.get_num_threads()
    try:
        for n in sorted({1, threads}):  # the per-thread accumulators change nothing
            numba.set_num_threads(n)
            counts, sums = ball_sums(x, radii)
            assert counts.shape == (len(x), len(radii)) and sums.shape == (len(x), len(radii), 3)
            for j, delta in enumerate(radii):
                k = d2 <= delta**2
                np.testing.assert_array_equal(counts[:, j], k.sum(1))
                np.testing.assert_allclose(sums[:, j], k.astype(float) @ x, rtol=1e-10, atol=1e-9)
    finally:
        numba.set_num_threads(threads)


def test_ball_sums_on_lattice_boundary_is_inclusive():
    # Points at exactly distance δ are neighbours, as in the dense formulation; the lattice
    # spacing equals the grid cell, so neighbours sit exactly on cell boundaries.
    g = np.stack(np.meshgrid(*[np.arange(4.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
    counts, _ = ball_sums(g, (1.0,))
    assert counts[0, 0] == 4  # corner: itself + 3 axis neighbours
    np.testing.assert_array_equal(counts[:, 0], (((g[:, None] - g[None]) ** 2).sum(-1) <= 1).sum(1))
    counts, _ = ball_sums(g, (1.0, 1.5, 2.0))
    # + 3 face diagonals (d² = 2); + the body diagonal (d² = 3) and 3 points at exactly d² = 4
    np.testing.assert_array_equal(counts[0], [4, 7, 11])


def test_ball_sums_rejects_bad_input():
    for points, radii in [
        (np.zeros((3, 2)), BWS),
        (np.array([[0.0, np.nan, 0.0]]), BWS),
        (np.zeros((3, 3)), (0.0, 1.0)),
        (np.zeros((3, 3)), ()),
    ]:
        with pytest.raises(ValueError):
            ball_sums(points, radii)
    counts, sums = ball_sums(np.zeros((0, 3)), BWS)
    assert counts.shape == (0, 3) and sums.shape == (0, 3, 3)


@pytest.mark.parametrize("kernel", [ShiftKernel.FLAT, ShiftKernel.GAUSSIAN])
def test_module_sparse_matches_dense_forward_and_gradients(kernel):
    torch.manual_seed(0)
    x = torch.from_numpy(lidar_like(np.random.default_rng(7), 600)).double()
    f = torch.randn(len(x), 8, dtype=torch.double)
    module = DynamicShift(8, BWS, iterations=3, hidden=16, kernel=kernel).double()
    sparse = module(x, f)
    dense = dense_forward(module, x, f)
    assert len(sparse.positions) == len(dense) == 4
    for a, b in zip(sparse.positions, dense):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-5)
    gt = x + torch.randn_like(x)
    grads = []
    for positions in (sparse.positions, dense):
        module.zero_grad()
        dynamic_shift_loss(positions[1:], gt).backward()
        grads.append([p.grad.clone() for p in module.parameters()])
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-5)
    assert all(torch.isfinite(g).all() for g in grads[0])
    assert any(g.abs().sum() > 0 for g in grads[0])


def test_gaussian_cutoff_is_a_small_truncation():
    x = torch.from_numpy(lidar_like(np.random.default_rng(3), 400))
    bw = torch.full((len(x),), 1.0, dtype=torch.double)
    full = dense_gaussian_means(x, bw, cutoff=None)
    cut = gaussian_kernel_means(x, bw, cutoff=3.0)
    torch.testing.assert_close(cut, dense_gaussian_means(x, bw, cutoff=3.0), rtol=0, atol=1e-10)
    assert 0 < (cut - full).norm(dim=1).max() < 0.3


def test_gaussian_bandwidth_gradient_matches_finite_differences():
    x = torch.from_numpy(lidar_like(np.random.default_rng(5), 200))
    bw = torch.rand(len(x), dtype=torch.double, generator=torch.Generator().manual_seed(0)) + 0.3
    bw.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda b: gaussian_kernel_means(x, b, cutoff=3.0), (bw,))


# ---------------------------------------------------------------- gradient formula
def test_gradient_follows_appendix_eq_13_to_17():
    torch.manual_seed(1)
    x = torch.tensor([[0.0, 0, 0], [0.15, 0, 0], [1.0, 0.2, 0], [3.0, 0, 0], [9.0, 9, 9]])
    x = x.double().requires_grad_(True)
    f = torch.randn(5, 4, dtype=torch.double)
    mlp = torch.nn.Sequential(torch.nn.Linear(4, 6), torch.nn.Tanh(), torch.nn.Linear(6, 3))
    mlp = mlp.double()
    w = torch.softmax(mlp(f), 1)  # eq. 9
    y = flat_shift_step(x, w, BWS)  # eq. 10-12
    gt = torch.randn(5, 3, dtype=torch.double)
    c = (y - gt).abs().sum()
    dc_dw_auto, dc_dx = torch.autograd.grad(c, (w, x), retain_graph=True, allow_unused=True)
    s = torch.from_numpy(dense_flat_means(x.detach().numpy(), BWS))  # S_j, constants
    dc_dy = torch.sign(y - gt).detach()  # eq. 17
    dc_dw = (s * dc_dy[:, None, :]).sum(-1)  # eq. 15-16
    torch.testing.assert_close(dc_dw_auto, dc_dw, rtol=0, atol=1e-12)
    assert dc_dx is None  # S_j has no gradient
    # eq. 13-14: chain through f = softmax(MLP) with ∂c/∂w_j
    auto = torch.autograd.grad(c, list(mlp.parameters()), retain_graph=True)
    chained = torch.autograd.grad(w, list(mlp.parameters()), grad_outputs=dc_dw)
    for a, b in zip(auto, chained):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12)


# ---------------------------------------------------------------- edge cases
EDGE_CASES = {
    "empty": np.zeros((0, 3)),
    "single": np.array([[1.0, 2.0, 3.0]]),
    "fewer_seeds_than_bandwidths": np.array([[0.0, 0, 0], [0.1, 0, 0]]),
    "isolated_seeds": np.array([[0.0, 0, 0], [50.0, 0, 0], [0, 80.0, 0]]),
    "identical": np.full((300, 3), 4.2),
}


@pytest.mark.parametrize("kernel", [ShiftKernel.FLAT, ShiftKernel.GAUSSIAN])
@pytest.mark.parametrize("case", sorted(EDGE_CASES))
def test_edge_cases_have_no_nan(case, kernel):
    x = torch.from_numpy(EDGE_CASES[case]).float()
    f = torch.randn(len(x), 5)
    module = DynamicShift(5, BWS, iterations=2, hidden=8, kernel=kernel)
    out = module(x, f)
    for p in out.positions + out.weights + out.bandwidths:
        assert torch.isfinite(p).all()
        assert len(p) == len(x)
    loss = dynamic_shift_loss(out.positions[1:], x)
    loss.backward()
    assert torch.isfinite(loss)
    assert all(torch.isfinite(p.grad).all() for p in module.parameters() if p.grad is not None)
    if case in ("single", "isolated_seeds", "identical"):  # nothing to move towards
        torch.testing.assert_close(out.final, x, rtol=0, atol=1e-5)
    labels = cluster_seeds(out.final.detach().numpy(), MeanShift(bandwidth=0.65))
    ids = assign_to_seeds(EDGE_CASES[case], out.final.detach().numpy(), labels)
    assert ids.shape == (len(x),) and (len(x) == 0 or ids.min() >= 0)


def test_weights_and_implied_bandwidth():
    out = DynamicShift(4, (0.3, 1.0), iterations=3)(torch.randn(50, 3), torch.randn(50, 4))
    assert len(out.weights) == len(out.bandwidths) == 3
    for w, b in zip(out.weights, out.bandwidths):
        torch.testing.assert_close(w.sum(1), torch.ones(50))
        torch.testing.assert_close(b, w[:, 0] * 0.3 + w[:, 1] * 1.0)
        assert ((b >= 0.3) & (b <= 1.0)).all()


def test_invalid_arguments():
    with pytest.raises(ValueError):
        DynamicShift(4, (0.0, 1.0))
    with pytest.raises(ValueError):
        DynamicShift(4, iterations=0)
    with pytest.raises(ValueError):
        DynamicShift(4)(torch.zeros(3, 2), torch.zeros(3, 4))
    assert DynamicShift(4, kernel="gaussian").kernel is ShiftKernel.GAUSSIAN
    assert "bandwidths=(0.2, 1.7, 3.2)" in repr(DynamicShift(4))


# ---------------------------------------------------------------- seeds, loss
def test_fps_is_deterministic_and_spread():
    pts = lidar_like(np.random.default_rng(0), 4000)
    a, b = select_seeds(pts, 500), select_seeds(pts, 500)
    np.testing.assert_array_equal(a, b)
    assert len(np.unique(a)) == 500 and a.dtype == np.int64
    np.testing.assert_array_equal(select_seeds(pts[:300], 500), np.arange(300))
    # FPS covers the extent far better than the first 500 points would
    assert np.ptp(pts[a], axis=0).min() >= 0.95 * np.ptp(pts, axis=0).min()
    assert len(select_seeds(np.zeros((0, 3)), 10)) == 0
    assert len(np.unique(select_seeds(np.full((50, 3), 1.0), 10))) == 10


def test_loss_value_by_hand():
    x1 = torch.tensor([[0.0, 0, 0], [1.0, 1, 1]])
    x2 = torch.tensor([[1.0, 0, 0], [1.0, 1, 2]])
    gt = torch.tensor([[1.0, 0, 0], [1.0, 1, 3]])
    # iteration 1: (1 + 2) / 2 = 1.5; iteration 2: (0 + 1) / 2 = 0.5
    assert dynamic_shift_loss([x1, x2], gt).item() == pytest.approx(2.0)
    assert dynamic_shift_loss([x1, x2], gt, (1.0, 0.5)).item() == pytest.approx(1.75)
    with pytest.raises(ValueError):
        dynamic_shift_loss([x1, x2], gt, (1.0,))


# ---------------------------------------------------------------- clustering
def blobs(rng: np.random.Generator):
    """A 6 m strip (car-like), two tight pedestrians 1 m apart, a sparse far blob."""
    strip = np.c_[rng.uniform(-3, 3, 300), rng.normal(0, 0.25, (300, 2))]
    ped1 = rng.normal(0, 0.08, (80, 3)) + [0, 4, 0]
    ped2 = rng.normal(0, 0.08, (80, 3)) + [1.0, 4, 0]
    sparse = rng.normal(0, 0.35, (25, 3)) + [-6, -6, 0]
    x = np.concatenate([strip, ped1, ped2, sparse])
    labels = np.repeat([0, 1, 2, 3], [300, 80, 80, 25])
    kind = np.repeat([0, 1, 1, 2], [300, 80, 80, 25])  # what a backbone feature would know
    centres = np.array([[0, 0, 0], [0, 4, 0], [1, 4, 0], [-6, -6, 0]], float)[labels]
    return x, labels, np.eye(3)[kind], centres


def test_dynamic_shift_separates_blobs_a_fixed_bandwidth_cannot():
    torch.manual_seed(0)
    x, labels, feats, centres = blobs(np.random.default_rng(0))
    xt, ft, ct = (torch.from_numpy(a).float() for a in (x, feats, centres))
    module = DynamicShift(3, BWS, iterations=4, hidden=16)
    opt = torch.optim.Adam(module.parameters(), lr=0.05)
    for _ in range(40):
        opt.zero_grad()
        loss = dynamic_shift_loss(module(xt, ft).positions[1:], ct)
        loss.backward()
        opt.step()
    with torch.no_grad():
        out = module(xt, ft)
    seed_labels = cluster_seeds(out.final.numpy(), MeanShift(bandwidth=0.65))
    pred = assign_to_seeds(x, x, seed_labels)
    assert adjusted_rand_score(labels, pred) > 0.99
    # The learned bandwidths follow the instance sizes: large for the strip, small for people.
    bw = out.bandwidths[0].numpy()
    assert bw[labels == 0].mean() > 1.5 > 0.5 > bw[(labels == 1) | (labels == 2)].mean()
    # A fixed bandwidth either splits the strip or merges the pedestrians.
    for bandwidth in (0.65, 3.2):
        fixed = MeanShift(bandwidth=bandwidth).fit_predict(x)
        assert adjusted_rand_score(labels, fixed) < 0.9
