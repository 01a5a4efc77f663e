"""Parity with the official DS-Net code: state-dict layout, import, effective kernels, DS MLP.

The expected key names and shapes below were written down from reading the official code
(hongfz16/DS-Net ``network/modules/spconv_unet.py``, ``PointNet.py``, ``pytorch_meanshift.py``,
``model_zoo.py``, ``cfgs/release/dsnet.yaml``), independently of ``official/keymap.py``.
"""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as tnf

from panoptic_bench.dsnet.checkpoint import build_backbone, build_shift
from panoptic_bench.dsnet.config import DSNetConfig, NetworkVariant
from panoptic_bench.dsnet.official.convert import convert_state, official_config
from panoptic_bench.dsnet.official.keymap import official_rules
from panoptic_bench.dsnet.sparse import SparseTensor, SubMConv3d
from panoptic_bench.dsnet.sparse.functional import weight_to_dense

# (official key, shape) facts, spconv 1.x layout (k0, k1, k2, in, out); INIT_SIZE 32
FACTS_STEP1 = {
    "vfe_model.PPmodel.0.weight": (9,),
    "vfe_model.PPmodel.1.weight": (64, 9),
    "vfe_model.PPmodel.4.weight": (128, 64),
    "vfe_model.PPmodel.7.weight": (256, 128),
    "vfe_model.PPmodel.8.running_var": (256,),
    "vfe_model.PPmodel.10.weight": (64, 256),
    "fea_compression.0.weight": (16, 64),
    "backbone.downCntx.conv1.weight": (1, 3, 3, 16, 32),
    "backbone.downCntx.conv1_2.weight": (3, 1, 3, 32, 32),
    "backbone.downCntx.conv2.weight": (3, 1, 3, 16, 32),
    "backbone.downCntx.conv3.weight": (1, 3, 3, 32, 32),
    "backbone.downCntx.bn0.num_batches_tracked": (),
    "backbone.resBlock2.conv1.weight": (3, 1, 3, 32, 64),
    "backbone.resBlock2.conv1_2.weight": (1, 3, 3, 64, 64),
    "backbone.resBlock2.conv2.weight": (1, 3, 3, 32, 64),
    "backbone.resBlock2.conv3.weight": (3, 1, 3, 64, 64),
    "backbone.resBlock2.pool.weight": (3, 3, 3, 64, 64),
    "backbone.resBlock5.pool.weight": (3, 3, 3, 512, 512),
    "backbone.upBlock0.trans_dilao.weight": (3, 3, 3, 512, 512),
    "backbone.upBlock0.up_subm.weight": (3, 3, 3, 512, 512),
    "backbone.upBlock1.trans_dilao.weight": (3, 3, 3, 512, 256),
    "backbone.upBlock3.conv1.weight": (1, 3, 3, 64, 64),
    "backbone.upBlock3.conv2.weight": (3, 1, 3, 64, 64),
    "backbone.upBlock3.conv3.weight": (3, 3, 3, 64, 64),
    "backbone.upBlock3.bn3.weight": (64,),
    "backbone.ReconNet.conv1.weight": (3, 1, 1, 64, 64),
    "backbone.ReconNet.conv1_2.weight": (1, 3, 1, 64, 64),
    "backbone.ReconNet.conv1_3.weight": (1, 1, 3, 64, 64),
    "backbone.ReconNet.bn0_3.running_mean": (64,),
    "sem_head.logits.weight": (3, 3, 3, 128, 20),
    "sem_head.logits.bias": (20,),
}
FACTS_STEP2 = {
    "ins_head.conv1.weight": (3, 3, 3, 128, 128),
    "ins_head.conv2.weight": (3, 3, 3, 128, 64),
    "ins_head.conv3.weight": (3, 3, 3, 64, 32),
    "ins_head.bn3.weight": (32,),
    "ins_head.offset.0.weight": (32, 35),
    "ins_head.offset.1.running_var": (32,),
    "ins_head.offset_linear.weight": (3, 32),
    "ins_head.offset_linear.bias": (3,),
}
MS = "pytorch_meanshift.learnable_bandwidth_weights_layer_list"
FACTS_STEP3 = {
    **{f"{MS}.{i}.0.weight": (32, 32) for i in range(4)},
    **{f"{MS}.{i}.1.running_mean": (32,) for i in range(4)},
    **{f"{MS}.{i}.3.weight": (3, 32) for i in range(4)},
    **{f"{MS}.{i}.3.bias": (3,) for i in range(4)},
}
# module counts: 5 BN tensors, 2 per Linear, 1 per bias-free conv
N_STEP1 = (4 * 5 + 4 * 2) + 2 + 4 * (1 + 5) + 4 * (4 * 6 + 1) + 4 * (4 * 6 + 1) + 3 * 6 + 2
N_STEP2 = N_STEP1 + 3 * 6 + 2 + 5 + 2
N_STEP3 = N_STEP2 + 4 * (2 + 5 + 2)


@pytest.mark.parametrize(
    ("step", "facts", "count"),
    [
        (1, FACTS_STEP1, N_STEP1),
        (2, {**FACTS_STEP1, **FACTS_STEP2}, N_STEP2),
        (3, {**FACTS_STEP1, **FACTS_STEP2, **FACTS_STEP3}, N_STEP3),
    ],
)
def test_official_layout_of_each_step(step, facts, count):
    rules = {r.official: r for r in official_rules(step)}
    assert len(rules) == count == len(official_rules(step))
    for key, shape in facts.items():
        assert rules[key].shape == shape, key
    later = {1: ("ins_head", MS), 2: (MS,), 3: ("no later step",)}[step]
    assert not [k for k in rules if k.startswith(later)]


def test_official_network_state_dict_is_the_mapped_layout():
    cfg = official_config()
    assert cfg.model.variant is NetworkVariant.OFFICIAL
    bb, sh = build_backbone(cfg, 20), build_shift(cfg, cfg.model.init_size)
    rules = official_rules(3)
    ours_b = {r.ours: r for r in rules if r.target == "backbone"}
    ours_s = {r.ours: r for r in rules if r.target == "shift"}
    assert set(bb.state_dict()) == set(ours_b)
    assert set(sh.state_dict()) == set(ours_s)
    for k, v in bb.state_dict().items():
        r = ours_b[k]
        want = (math.prod(r.shape[:3]), *r.shape[3:]) if r.conv else r.shape
        assert tuple(v.shape) == want, k


def random_official_state(step: int, seed: int = 0, prefix: str = "module.") -> dict:
    g = torch.Generator().manual_seed(seed)
    state = {}
    for r in official_rules(step):
        if r.official.endswith("num_batches_tracked"):
            state[prefix + r.official] = torch.tensor(3)
        elif r.official.endswith("running_var"):
            state[prefix + r.official] = torch.rand(r.shape, generator=g) + 0.5
        else:
            state[prefix + r.official] = torch.randn(r.shape, generator=g) * 0.05
    return state


def test_random_official_state_converts_and_loads_strictly():
    state = {k.removeprefix("module."): v for k, v in random_official_state(3).items()}
    res = convert_state(state)
    assert res.step == 3 and res.shift is not None
    cfg = official_config()
    bb, sh = build_backbone(cfg, 20), build_shift(cfg, 32)
    assert bb.load_state_dict(res.backbone, strict=True).missing_keys == []
    assert sh.load_state_dict(res.shift, strict=True).missing_keys == []
    w = state["backbone.resBlock3.conv1.weight"]  # (3, 1, 3, 64, 128)
    torch.testing.assert_close(
        bb.unet.down[1].residual.branch_b[0].conv.weight, w.reshape(9, 64, 128)
    )
    # spconv 2.x layout (out, k0, k1, k2, in) of the same weights converts to the same tensors
    v2 = {k: v.permute(4, 0, 1, 2, 3).contiguous() if v.ndim == 5 else v for k, v in state.items()}
    res2 = convert_state(v2)
    assert all(torch.equal(res2.backbone[k], res.backbone[k]) for k in res.backbone)


def _effective_layers(init_size: int = 4):
    cfg = DSNetConfig.from_dict({"model": {"variant": "official", "init_size": init_size}})
    unet = build_backbone(cfg, 5).unet
    return [m for m in unet.modules() if isinstance(m, SubMConv3d)]


def test_effective_kernels_of_the_official_network():
    layers = _effective_layers()
    pairs = {(m.kernel_size, m.effective_kernel) for m in layers}
    assert pairs == {
        ((1, 3, 3), (1, 3, 3)),  # context conv1 / conv3, up refine conv1
        ((3, 1, 3), (1, 3, 3)),  # context conv1_2 / conv2, up refine conv2
        ((3, 1, 3), (3, 1, 3)),  # down conv1 / conv3
        ((1, 3, 3), (3, 1, 3)),  # down conv1_2 / conv2
        ((3, 3, 3), (3, 3, 3)),  # up trans_dilao (its own key)
        ((3, 3, 3), (1, 3, 3)),  # up refine conv3: first kernel plane
        ((3, 1, 1), (3, 1, 1)),
        ((1, 3, 1), (3, 1, 1)),
        ((1, 1, 3), (3, 1, 1)),
    }
    nominal = DSNetConfig.from_dict({"model": {"init_size": 4}})
    assert all(
        m.effective_kernel == m.kernel_size
        for m in build_backbone(nominal, 5).unet.modules()
        if isinstance(m, SubMConv3d)
    )


def test_each_effective_kernel_layer_equals_dense_conv3d():
    shape = (7, 6, 5)
    g = torch.Generator().manual_seed(3)
    coords = torch.nonzero(torch.rand((1, *shape), generator=g) < 0.35).to(torch.int32)
    seen = set()
    for layer in _effective_layers():
        key = (layer.kernel_size, layer.effective_kernel, layer.in_channels, layer.out_channels)
        if key in seen:
            continue
        seen.add(key)
        feats = torch.randn(len(coords), layer.in_channels, generator=g, dtype=torch.float64)
        x = SparseTensor(feats, coords, shape)
        layer64 = layer.double()
        out = layer64(x).features
        eff = layer.effective_kernel
        n = math.prod(eff)
        dense_w = weight_to_dense(layer64.weight[:n].detach(), eff)  # (out, in, *eff)
        ref = tnf.conv3d(x.dense(), dense_w, padding=tuple(k // 2 for k in eff))
        c = coords.long()
        ref = ref[c[:, 0], :, c[:, 1], c[:, 2], c[:, 3]]
        torch.testing.assert_close(out, ref, atol=1e-10, rtol=1e-10)
    assert len({k[:2] for k in seen}) == 9


def test_ds_mlp_with_batchnorm_in_eval_mode():
    cfg = official_config()
    shift = build_shift(cfg, 32)
    mlp = shift.mlps[2]
    assert [type(m).__name__ for m in mlp] == ["Linear", "BatchNorm1d", "ReLU", "Linear"]
    assert tuple(mlp[0].weight.shape) == (32, 32) and tuple(mlp[3].weight.shape) == (3, 32)
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        bn = mlp[1]
        bn.running_mean.copy_(torch.randn(32, generator=g))
        bn.running_var.copy_(torch.rand(32, generator=g) + 0.5)
        bn.weight.copy_(torch.randn(32, generator=g))
        bn.bias.copy_(torch.randn(32, generator=g))
    shift.eval()
    x = torch.randn(6, 32, generator=g)
    h = x @ mlp[0].weight.T + mlp[0].bias
    h = (h - bn.running_mean) / torch.sqrt(bn.running_var + bn.eps) * bn.weight + bn.bias
    ref = torch.relu(h) @ mlp[3].weight.T + mlp[3].bias
    with torch.no_grad():
        torch.testing.assert_close(mlp(x), ref)
        torch.testing.assert_close(mlp(x[:1]), ref[:1])  # eval: no batch statistics
        out = shift(torch.randn(6, 3, generator=g), x)
    assert len(out.weights) == 4 and torch.allclose(out.weights[2].sum(1), torch.ones(6))


def _official_rule_by_hand(scan, size, lo, hi):
    """The official dataloader's rule re-derived per axis (``dataloader/dataset.py``).

    Polar coordinates in the scan's float32; bounds, cell ``(max - min) / (size - 1)``,
    clipping, flooring and voxel centres in float64; features stacked as
    ``[rel rho, rel phi, rel z, rho, phi, z, x, y, remission]``.
    """
    import numpy as np

    x, y, z, r = (scan[:, i] for i in range(4))
    polar = [np.sqrt(x * x + y * y), np.arctan2(y, x), z]  # float32 each
    idx, rel = [], []
    for axis in range(3):
        cell = (hi[axis] - lo[axis]) / (size[axis] - 1)
        v = np.minimum(np.maximum(polar[axis].astype(np.float64), lo[axis]), hi[axis])
        i = np.floor((v - lo[axis]) / cell).astype(np.int64)
        centre = (i.astype(np.float32).astype(np.float64) + 0.5) * cell + lo[axis]
        idx.append(i)
        rel.append(polar[axis].astype(np.float64) - centre)
    feats = np.stack([*rel, *polar, x, y, r], axis=1).astype(np.float32)
    return np.stack(idx, axis=1), feats


@pytest.mark.parametrize("frame", ["000000", "000001", "000002"])
def test_voxelizer_equals_the_official_rule_on_real_scans(kitti_root, frame):
    import numpy as np

    from panoptic_bench.dsnet.checkpoint import build_grid
    from panoptic_bench.dsnet.model.voxelize import collate, voxel_indices

    scan = np.fromfile(kitti_root / "sequences" / "00" / "velodyne" / f"{frame}.bin", np.float32)
    scan = scan.reshape(-1, 4)
    cfg = official_config()
    grid = build_grid(cfg)
    assert grid.official_cells and grid.size == (480, 360, 32)
    lo, hi = (3.0, -np.pi, -3.0), (50.0, np.pi, 1.5)
    idx_ref, feats_ref = _official_rule_by_hand(scan, grid.size, lo, hi)
    batch = collate([scan], grid)
    coords = batch.voxel_coords[batch.point_voxel].numpy()
    assert coords[:, 0].max() == 0
    assert np.array_equal(coords[:, 1:], idx_ref)  # every point's voxel
    assert np.array_equal(voxel_indices(torch.from_numpy(scan[:, :3]), grid).numpy(), idx_ref)
    np.testing.assert_allclose(batch.point_features.numpy(), feats_ref, rtol=0, atol=1e-6)
    assert idx_ref.max(0).tolist() <= [479, 359, 31] and idx_ref.min() >= 0
    # the nominal rule (range / size) puts only about a quarter of the points in the same voxel
    nominal = DSNetConfig.from_dict({})
    same = voxel_indices(torch.from_numpy(scan[:, :3]), build_grid(nominal)).numpy() == idx_ref
    assert 0.1 < same.all(1).mean() < 0.5


def test_paper_configs_build_the_official_network():
    from pathlib import Path

    from panoptic_bench.dsnet.config import load_config

    configs = Path(__file__).resolve().parents[1] / "configs"
    official = official_config()
    for name in ("dsnet_semantickitti.yaml", "dsnet_nuscenes.yaml"):
        cfg = load_config(configs / name)
        assert cfg.model == official.model, name
        assert cfg.grid == official.grid, name
        assert cfg.dynamic_shift.bandwidths == official.dynamic_shift.bandwidths


def test_the_official_network_trains_all_three_stages(tmp_path, one_torch_thread):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from dsnet_tiny_world import write_tiny_world
    from test_dsnet_train import TINY

    from panoptic_bench.dsnet.checkpoint import load_checkpoint
    from panoptic_bench.dsnet.training.train import train

    world = write_tiny_world(tmp_path / "world", {"00": 2, "08": 1})
    raw = {k: dict(v) for k, v in TINY.items()}
    raw["model"]["variant"] = "official"
    cfg = DSNetConfig.from_dict(raw)
    for stage in ("semantic", "offset", "ds"):
        train(cfg, world, tmp_path / "run", stage=stage, progress=False)
    ck = load_checkpoint(tmp_path / "run" / "checkpoints" / "ds.pt")
    assert ck.config.model.variant is NetworkVariant.OFFICIAL and ck.shift is not None
    assert "mlps.0.1.running_mean" in ck.shift  # the DS MLP's BatchNorm was trained
    assert not torch.equal(ck.shift["mlps.0.1.running_mean"], torch.zeros(4))


def test_official_ds_rules_seeds_on_xyz_and_nearest_seed_by_xyz():
    import numpy as np

    from panoptic_bench.dsnet.config import Clusterer
    from panoptic_bench.dsnet.inference.clustering import make_clusterer
    from panoptic_bench.dsnet.inference.official import (
        official_seed_count,
        official_seeds,
        official_shift_instances,
    )

    assert official_seed_count(40, 50) == 40 and official_seed_count(10000, 10000) == 10000
    assert official_seed_count(300, 50) in (50, 51)
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.normal(0, 0.3, (150, 3)), rng.normal(20, 0.3, (150, 3))])
    centres = pts + rng.normal(0, 0.05, pts.shape)
    idx = official_seeds(pts, 50)
    assert idx[0] == 0 and len(idx) == official_seed_count(300, 50) == len(set(idx.tolist()))
    assert official_seeds(pts, 300) is None
    d = np.linalg.norm(pts[:, None] - pts[idx][None], axis=2).min(1)  # FPS covers the points
    assert d.max() <= np.linalg.norm(pts[idx[-1]] - pts[idx[:-1]], axis=1).min() + 1e-6
    cfg = DSNetConfig.from_dict({"model": {"variant": "official", "init_size": 4}})
    torch.manual_seed(0)
    shift = build_shift(cfg, 4).eval()
    feats = torch.randn(300, 4)
    ms = make_clusterer(Clusterer.MEANSHIFT, 0.65)
    inst, diag = official_shift_instances(shift, pts, centres, feats, ms, max_seeds=50)
    assert inst.min() >= 1 and set(inst[:150]).isdisjoint(inst[150:])
    seed_lab = diag["seed_labels"] + 1
    nearest = np.linalg.norm(pts[:, None] - pts[idx][None], axis=2).argmin(1)
    assert np.array_equal(inst, seed_lab[nearest])  # nearest seed by xyz, label + 1
    one, _ = official_shift_instances(shift, pts[:1], centres[:1], feats[:1], ms, max_seeds=50)
    assert one.tolist() == [0]  # a single seed: no instance
