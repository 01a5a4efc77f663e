#!/usr/bin/env bash
# The CUDA checks, for a machine with a GPU and a CUDA build of PyTorch (docs/DEVELOPING.md, "CUDA").
# Uses that machine's python3 (PYTHON overrides) with this checkout first on PYTHONPATH, installs
# nothing, and needs ../shared/data/semantickitti and panoptic_bench/checkpoints/dsnet_semantickitti_cpu.pt.
# Steps (arguments; default all):
#   tests  tests/test_cuda.py: sparse convolutions, the shipped real-data model, train / infer / DDP
#          (nccl) on CUDA against the CPU
#   infer  benchmarks/bench_infer.py --device cuda (per-frame cost on the GPU)
#   train  one semantic-stage epoch of configs/dsnet_synthetic_materials_paste_cpu.yaml on 24 synthetic
#          scans (realistic world, made here first) on cuda, then on the CPU at 2 and at all threads
# Output: ${OUT:-cuda-check}/ (env.txt, pytest_cuda.txt, bench_infer_cuda.log, infer_cuda.md,
# train_<device>.csv, train_speed.txt).
set -uo pipefail
OUT=${OUT:-$PWD/cuda-check}
PY=${PYTHON:-python3}
STEPS=${*:-tests infer train}
mkdir -p "$OUT"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
{
    nvidia-smi -L
    $PY -c "import torch, numpy; print('torch', torch.__version__, 'cuda', torch.version.cuda, \
torch.cuda.get_device_name(0), 'numpy', numpy.__version__)"
} 2>&1 | tee "$OUT/env.txt"
rc=0
if [[ " $STEPS " == *" tests "* ]]; then
    $PY -m pytest -q -ra -p no:cacheprovider tests/test_cuda.py 2>&1 | tee "$OUT/pytest_cuda.txt"
    rc=$?
fi
if [[ " $STEPS " == *" infer "* ]]; then
    $PY benchmarks/bench_infer.py --device cuda --configs cpu,official --frames 3 --threads 4 \
        2>&1 | tee "$OUT/bench_infer_cuda.log"
    cp benchmarks/results/infer.md "$OUT/infer_cuda.md" 2>/dev/null
fi
if [[ " $STEPS " == *" train "* ]]; then
    W=$(mktemp -d)
    $PY -m panoptic_bench synth semantickitti --out "$W/world" --profile realistic \
        --sequences 00:${TRAIN_SCANS:-24},08:2 >/dev/null || rc=1
    all=$(nproc)
    for run in "cuda 2" "cpu 2" "cpu $all"; do
        set -- $run
        start=$(date +%s.%N)
        $PY -m panoptic_bench train --config configs/dsnet_synthetic_materials_paste_cpu.yaml \
            --data "$W/world" --out "$W/run_$1_$2" --stage semantic --epochs 1 \
            --train-sequences 00 --val-sequences 08 --device "$1" --threads "$2" --no-progress \
            >/dev/null || rc=1
        end=$(date +%s.%N)
        cp "$W/run_$1_$2/metrics.csv" "$OUT/train_$1_$2.csv"
        epoch=$(tail -n 1 "$W/run_$1_$2/metrics.csv" | awk -F, '{print $NF}')
        echo "$1 threads=$2: epoch of ${TRAIN_SCANS:-24} scans ${epoch} s (metrics.csv), whole process" \
            "$($PY -c "print(round($end - $start, 1))") s" | tee -a "$OUT/train_speed.txt"
    done
fi
exit $rc
