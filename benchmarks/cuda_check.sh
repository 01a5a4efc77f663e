#!/usr/bin/env bash
# The CUDA checks, for a machine with a GPU and a CUDA build of PyTorch (docs/DEVELOPING.md, "CUDA").
# Uses that machine's python3 (PYTHON overrides) with this checkout first on PYTHONPATH, installs
# nothing, and needs ../shared/data/semantickitti and panoptic_bench/checkpoints/dsnet_semantickitti_cpu.pt.
# 1. tests/test_cuda.py: sparse convolutions, the shipped real-data model, train / infer / DDP (nccl)
#    on CUDA against the CPU;  2. benchmarks/bench_infer.py --device cuda (per-frame cost on the GPU).
# Output: ${OUT:-cuda-check}/ (env.txt, pytest_cuda.txt, bench_infer_cuda.log, infer_cuda.md).
set -uo pipefail
OUT=${OUT:-$PWD/cuda-check}
PY=${PYTHON:-python3}
mkdir -p "$OUT"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
{
    nvidia-smi -L
    $PY -c "import torch, numpy; print('torch', torch.__version__, 'cuda', torch.version.cuda, \
torch.cuda.get_device_name(0), 'numpy', numpy.__version__)"
} 2>&1 | tee "$OUT/env.txt"
$PY -m pytest -q -ra -p no:cacheprovider tests/test_cuda.py 2>&1 | tee "$OUT/pytest_cuda.txt"
rc=$?
$PY benchmarks/bench_infer.py --device cuda --configs cpu,official --frames 3 --threads 4 \
    2>&1 | tee "$OUT/bench_infer_cuda.log"
cp benchmarks/results/infer.md "$OUT/infer_cuda.md" 2>/dev/null
exit $rc
