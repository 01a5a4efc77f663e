"""The official DS-Net state-dict layout, as data, and its mapping onto our modules.

Facts read from the official code (hongfz16/DS-Net: ``network/model_zoo.py``,
``network/modules/spconv_unet.py``, ``PointNet.py``, ``pytorch_meanshift.py``,
``cfgs/release/dsnet.yaml``), for its released SemanticKITTI configuration: ``INIT_SIZE`` 32,
``NCLASS`` 20, ``DATA_DIM`` 9, ``VFE.OUT_CHANNEL`` 64, ``FEATURE_COMPRESSION`` 16,
``EMBEDDING_CHANNEL`` 3, three bandwidth candidates, four shifting iterations.

The three released checkpoints hold (after any ``module.`` prefix of DataParallel / DDP):

- step 1 (``sem_pretrain.pth``, semantic): ``vfe_model.*``, ``fea_compression.*``,
  ``backbone.*``, ``sem_head.*``;
- step 2 (``offset_pretrain_pq_0.564.pth``): step 1 plus ``ins_head.*``;
- step 3 (``dsnet_pretrain_pq_0.577.pth``): step 2 plus
  ``pytorch_meanshift.learnable_bandwidth_weights_layer_list.*``.

Each may also hold ``sem_loss.weight`` (the buffer of the weighted cross-entropy, 20 class
weights): it is kept as the checkpoint's ``class_weights``, not as a weight.

spconv 1.x stores a conv weight as ``(k0, k1, k2, in, out)``, with the kernel offsets in the
same row-major order as our kernel maps: ours is a reshape to ``(k0 * k1 * k2, in, out)``.
spconv 2.x stores ``(out, k0, k1, k2, in)`` (a permutation first); both are accepted.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "KeyRule",
    "OFFICIAL_DIMS",
    "STEP_NAMES",
    "STEP_PREFIXES",
    "official_rules",
]

#: The released configuration's sizes (``cfgs/release/dsnet.yaml``).
OFFICIAL_DIMS = {
    "init_size": 32,
    "num_classes": 20,
    "data_dim": 9,
    "vfe_out": 64,
    "compression": 16,
    "embedding": 3,
    "bandwidths": 3,
    "iterations": 4,
}

#: Our checkpoint stage of each official training step.
STEP_NAMES = {1: "semantic", 2: "offset", 3: "ds"}

#: Top-level modules of the official model whose presence identifies each step.
STEP_PREFIXES = {
    1: ("vfe_model", "fea_compression", "backbone", "sem_head"),
    2: ("ins_head",),
    3: ("pytorch_meanshift",),
}


@dataclass(frozen=True)
class KeyRule:
    """One tensor of the official state dict.

    Attributes
    ----------
    official : str
        Key in the official state dict (without ``module.``).
    shape : tuple of int
        Its shape in the official (spconv 1.x) layout.
    ours : str
        Key in our state dict (``target``'s).
    target : str
        ``backbone`` (our :class:`PanopticBackbone`) or ``shift`` (our ``DynamicShift``).
    conv : bool
        A sparse-conv weight (spconv layout, reshaped to ``(k, in, out)``).
    step : int
        First training step (1, 2 or 3) whose checkpoint holds it.
    """

    official: str
    shape: tuple[int, ...]
    ours: str
    target: str
    conv: bool
    step: int


def _bn(rules: list, off: str, ours: str, c: int, target: str, step: int) -> None:
    for name in ("weight", "bias", "running_mean", "running_var"):
        rules.append(KeyRule(f"{off}.{name}", (c,), f"{ours}.{name}", target, False, step))
    rules.append(
        KeyRule(
            f"{off}.num_batches_tracked", (), f"{ours}.num_batches_tracked", target, False, step
        )
    )


def _linear(rules: list, off: str, ours: str, n_in: int, n_out: int, target: str, step: int):
    rules.append(KeyRule(f"{off}.weight", (n_out, n_in), f"{ours}.weight", target, False, step))
    rules.append(KeyRule(f"{off}.bias", (n_out,), f"{ours}.bias", target, False, step))


def _conv(rules: list, off: str, ours: str, k: tuple[int, int, int], n_in: int, n_out: int):
    rules.append(KeyRule(f"{off}.weight", (*k, n_in, n_out), f"{ours}.weight", "backbone", True, 0))


K133, K313, K333 = (1, 3, 3), (3, 1, 3), (3, 3, 3)


def _backbone_rules(w: int, d: dict) -> list[KeyRule]:
    r: list[KeyRule] = []
    # point encoder: PointNet PPmodel (BN, [Linear, BN, ReLU] x 3, Linear) and compression
    _bn(r, "vfe_model.PPmodel.0", "encoder.point_mlp.0", d["data_dim"], "backbone", 1)
    widths = (d["data_dim"], 64, 128, 256)
    for i, (a, b) in enumerate(zip(widths[:-1], widths[1:])):
        _linear(r, f"vfe_model.PPmodel.{1 + 3 * i}", f"encoder.point_mlp.{1 + 3 * i}", a, b,
                "backbone", 1)  # fmt: skip
        _bn(r, f"vfe_model.PPmodel.{2 + 3 * i}", f"encoder.point_mlp.{2 + 3 * i}", b, "backbone", 1)
    _linear(r, "vfe_model.PPmodel.10", "encoder.point_mlp.10", 256, d["vfe_out"], "backbone", 1)
    _linear(r, "fea_compression.0", "encoder.compress.0", d["vfe_out"], d["compression"],
            "backbone", 1)  # fmt: skip
    # context block: shortcut conv1 (1x3x3) -> conv1_2 (3x1x3); resA conv2 (3x1x3) -> conv3
    ctx = "backbone.downCntx"
    for off, bn, ours, k, a in (
        ("conv1", "bn0", "branch_a.0", K133, d["compression"]),
        ("conv1_2", "bn0_2", "branch_a.1", K313, w),
        ("conv2", "bn1", "branch_b.0", K313, d["compression"]),
        ("conv3", "bn2", "branch_b.1", K133, w),
    ):
        _conv(r, f"{ctx}.{off}", f"unet.context.{ours}.conv", k, a, w)
        _bn(r, f"{ctx}.{bn}", f"unet.context.{ours}.norm", w, "backbone", 1)
    # down blocks resBlock2..5: shortcut conv1 (3x1x3) -> conv1_2 (1x3x3); resA conv2 (1x3x3)
    # -> conv3 (3x1x3); strided pool conv (3x3x3, no bias)
    for i, (a, b) in enumerate(((w, 2 * w), (2 * w, 4 * w), (4 * w, 8 * w), (8 * w, 16 * w))):
        off, ours = f"backbone.resBlock{i + 2}", f"unet.down.{i}"
        for conv, bn, branch, k, n_in in (
            ("conv1", "bn0", "branch_b.0", K313, a),
            ("conv1_2", "bn0_2", "branch_b.1", K133, b),
            ("conv2", "bn1", "branch_a.0", K133, a),
            ("conv3", "bn2", "branch_a.1", K313, b),
        ):
            _conv(r, f"{off}.{conv}", f"{ours}.residual.{branch}.conv", k, n_in, b)
            _bn(r, f"{off}.{bn}", f"{ours}.residual.{branch}.norm", b, "backbone", 1)
        _conv(r, f"{off}.pool", f"{ours}.pool", K333, b, b)
    # up blocks upBlock0..3: trans_dilao (3x3x3) + trans_bn, up_subm (inverse, no bias),
    # conv1 (1x3x3), conv2 (3x1x3), conv3 (3x3x3), each with its BatchNorm
    for i, (a, b) in enumerate(((16 * w, 16 * w), (16 * w, 8 * w), (8 * w, 4 * w), (4 * w, 2 * w))):
        off, ours = f"backbone.upBlock{i}", f"unet.up.{i}"
        _conv(r, f"{off}.trans_dilao", f"{ours}.reduce.conv", K333, a, b)
        _bn(r, f"{off}.trans_bn", f"{ours}.reduce.norm", b, "backbone", 1)
        for j, (conv, bn, k) in enumerate(
            (("conv1", "bn1", K133), ("conv2", "bn2", K313), ("conv3", "bn3", K333))
        ):
            _conv(r, f"{off}.{conv}", f"{ours}.refine.{j}.conv", k, b, b)
            _bn(r, f"{off}.{bn}", f"{ours}.refine.{j}.norm", b, "backbone", 1)
        _conv(r, f"{off}.up_subm", f"{ours}.up", K333, b, b)
    # reconstruction block: conv1 (3x1x1), conv1_2 (1x3x1), conv1_3 (1x1x3) with bn0, bn0_2, bn0_3
    for j, (conv, bn, k) in enumerate(
        (
            ("conv1", "bn0", (3, 1, 1)),
            ("conv1_2", "bn0_2", (1, 3, 1)),
            ("conv1_3", "bn0_3", (1, 1, 3)),
        )
    ):
        _conv(r, f"backbone.ReconNet.{conv}", f"unet.recon.convs.{j}", k, 2 * w, 2 * w)
        _bn(r, f"backbone.ReconNet.{bn}", f"unet.recon.norms.{j}", 2 * w, "backbone", 1)
    # semantic head: one 3x3x3 conv with bias
    _conv(r, "sem_head.logits", "semantic_head.logits", K333, 4 * w, d["num_classes"])
    r.append(
        KeyRule(
            "sem_head.logits.bias",
            (d["num_classes"],),
            "semantic_head.logits.bias",
            "backbone",
            False,
            1,
        )  # fmt: skip
    )
    r = [KeyRule(x.official, x.shape, x.ours, "backbone", x.conv, 1) for x in r]
    # offset head (step 2): three 3x3x3 convs (conv -> BN -> LeakyReLU), point MLP
    ins: list[KeyRule] = []
    for j, (a, b) in enumerate(((4 * w, 4 * w), (4 * w, 2 * w), (2 * w, w))):
        _conv(ins, f"ins_head.conv{j + 1}", f"instance_head.convs.{j}.conv", K333, a, b)
        _bn(ins, f"ins_head.bn{j + 1}", f"instance_head.convs.{j}.norm", b, "backbone", 2)
    _linear(ins, "ins_head.offset.0", "instance_head.mlp.0", w + 3, w, "backbone", 2)
    _bn(ins, "ins_head.offset.1", "instance_head.mlp.1", w, "backbone", 2)
    _linear(ins, "ins_head.offset_linear", "instance_head.mlp.3", w, d["embedding"], "backbone", 2)
    return r + [KeyRule(x.official, x.shape, x.ours, "backbone", x.conv, 2) for x in ins]


def _shift_rules(w: int, d: dict) -> list[KeyRule]:
    r: list[KeyRule] = []
    base = "pytorch_meanshift.learnable_bandwidth_weights_layer_list"
    for i in range(d["iterations"]):
        _linear(r, f"{base}.{i}.0", f"mlps.{i}.0", w, w, "shift", 3)
        _bn(r, f"{base}.{i}.1", f"mlps.{i}.1", w, "shift", 3)
        _linear(r, f"{base}.{i}.3", f"mlps.{i}.3", w, d["bandwidths"], "shift", 3)
    return r


def official_rules(step: int = 3) -> list[KeyRule]:
    """Every tensor of the official checkpoint of ``step`` (1, 2 or 3), in module order.

    Examples
    --------
    >>> rules = official_rules(1)
    >>> rules[0].official, rules[0].shape, rules[0].ours
    ('vfe_model.PPmodel.0.weight', (9,), 'encoder.point_mlp.0.weight')
    """
    if step not in STEP_NAMES:
        raise ValueError(f"step must be 1, 2 or 3, got {step}")
    d = OFFICIAL_DIMS
    rules = _backbone_rules(d["init_size"], d) + _shift_rules(d["init_size"], d)
    return [r for r in rules if r.step <= step]
