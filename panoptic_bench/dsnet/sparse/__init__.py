"""Pure-PyTorch sparse convolution (CPU and CUDA), split into modules and functional ops.

>>> from panoptic_bench.dsnet.sparse import SparseTensor, SubMConv3d
"""

from panoptic_bench.dsnet.sparse.functional import (
    apply_kernel_map,
    dense_to_weight,
    inverse_conv3d,
    sparse_conv3d,
    submanifold_conv3d,
    weight_to_dense,
)
from panoptic_bench.dsnet.sparse.kmap import KernelMap, downsample_map, submanifold_map
from panoptic_bench.dsnet.sparse.modules import (
    SparseActivation,
    SparseBatchNorm,
    SparseConv3d,
    SparseInverseConv3d,
    SubMConv3d,
)
from panoptic_bench.dsnet.sparse.tensor import SparseTensor

__all__ = [
    "KernelMap",
    "SparseActivation",
    "SparseBatchNorm",
    "SparseConv3d",
    "SparseInverseConv3d",
    "SparseTensor",
    "SubMConv3d",
    "apply_kernel_map",
    "dense_to_weight",
    "downsample_map",
    "inverse_conv3d",
    "sparse_conv3d",
    "submanifold_conv3d",
    "submanifold_map",
    "weight_to_dense",
]
