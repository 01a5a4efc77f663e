"""The methods of the demo on the synthetic nuScenes dataroot.

With the shipped ``dsnet_nuscenes_synthetic.pt`` (a CPU DS-Net trained on a synthetic nuScenes
world of another seed, so the demo's world is unseen), the DS-Net row comes from the network
and the four clusterings also run on its regressed centres ("Backbone + X" rows). The
*simulated regression* rows (ground-truth semantics, noisy box centres) are always there,
labelled so, and so is box-merge with a simulated detector.
"""

from __future__ import annotations

from pathlib import Path

from panoptic_bench.demo import steps
from panoptic_bench.demo.boxmerge import BOX_MERGE_NOTE, box_merge_nuscenes_run
from panoptic_bench.demo.config import CLUSTERINGS, ClusteringSpec, DemoSize
from panoptic_bench.demo.evaluate import evaluate_nuscenes_run
from panoptic_bench.demo.kitti import SIMULATED_NOTE, DemoResult

__all__ = ["NUSCENES_CHECKPOINT", "run_nuscenes_methods"]

NUSCENES_CHECKPOINT = "dsnet_nuscenes_synthetic.pt"


def _meta(method: str, eval_set: str, data: str, notes: str, ablation: dict | None = None):
    meta = {"method": method, "dataset": "nuscenes", "split": eval_set, "data": data}
    meta["notes"] = notes
    if ablation is not None:
        meta["ablation"] = ablation
    return meta


def _evaluate(ws, eval_set: str, pred: Path, name: str, meta: dict, workers: int, result):
    run = ws.runs / name
    evaluate_nuscenes_run(
        ws.nuscenes, steps.NUS_VERSION, eval_set, pred, run, meta, workers=workers, show=ws.show
    )
    result.runs.append(run)


def _cluster(ws, eval_set, centres, spec: ClusteringSpec, name: str, workers: int) -> Path:
    pred = ws.predictions(name)
    steps.cluster_nuscenes_centres(ws.nuscenes, eval_set, centres, pred, spec, workers=workers)
    return pred


def _dsnet(ws, eval_set: str, data: str, workers: int, stages, result: DemoResult) -> None:
    """DS-Net row and the clusterings on its centres, when the checkpoint is shipped."""
    ckpt = steps.find_checkpoint(NUSCENES_CHECKPOINT)
    if ckpt is None:
        result.missing.append(
            f"nuScenes DS-Net: no shipped checkpoint panoptic_bench/checkpoints/"
            f"{NUSCENES_CHECKPOINT}; nuScenes rows use the simulated regression only"
        )
        return
    shown = steps.checkpoint_label(ckpt)
    trained = steps.TRAINED_ON.get(NUSCENES_CHECKPOINT, "")
    with stages(f"nuScenes DS-Net inference ({shown}, CPU)"):
        pred = ws.predictions("nuscenes-dsnet")
        method = steps.dsnet_regression(ckpt, ws.nuscenes, (eval_set,), pred)
    with stages(f"evaluate nuScenes {method}"):
        notes = f"checkpoint {shown}, CPU inference; {trained}; DS seeds clustered by BFS 1.2 m"
        meta = _meta(method, eval_set, data, notes, {"clustering": "Dynamic Shifting"})
        _evaluate(ws, eval_set, pred, "nuscenes-dsnet", meta, workers, result)
    for spec in CLUSTERINGS:
        with stages(f"{spec.describe()} on nuScenes DS-Net centres: cluster and evaluate"):
            name = f"nuscenes-backbone-{spec.key}"
            out = _cluster(ws, eval_set, pred, spec, name, workers)
            label = (
                "Backbone with Fusion" if spec.method == "meanshift" else f"Backbone + {spec.label}"
            )
            notes = (
                f"DS-Net backbone regression ({shown}; {trained}); clustering "
                f"{spec.describe()}, min 5 points, consensus fusion"
            )
            meta = _meta(label, eval_set, data, notes, {"clustering": spec.label})
            _evaluate(ws, eval_set, out, name, meta, workers, result)


def run_nuscenes_methods(
    ws: steps.Workspace,
    size: DemoSize,
    workers: int,
    stages,
    result: DemoResult,
    use_checkpoint: bool = True,
) -> None:
    """DS-Net (when shipped), the simulated-regression clusterings and box-merge on nuScenes."""
    eval_set = steps.NUS_EVAL_SET
    centres = ws.centres("nuscenes-simulated")
    with stages("simulated regression (nuScenes format, not a network result)"):
        n = steps.simulate_nuscenes_centres(
            ws.nuscenes, eval_set, centres, seed=size.seed, workers=workers
        )
    data = f"synthetic nuScenes {steps.NUS_VERSION} {eval_set} ({n} sweeps)"
    if use_checkpoint:
        _dsnet(ws, eval_set, data, workers, stages, result)
    for spec in CLUSTERINGS:
        with stages(f"{spec.describe()} on nuScenes: cluster and evaluate"):
            name = f"nuscenes-{spec.key}"
            pred = _cluster(ws, eval_set, centres, spec, name, workers)
            notes = (
                f"{SIMULATED_NOTE.format(seed=size.seed)}; clustering {spec.describe()}, "
                "min 5 points, consensus fusion"
            )
            meta = _meta(f"{spec.label} (simulated regression)", eval_set, data, notes)
            _evaluate(ws, eval_set, pred, name, meta, workers, result)
    with stages("box-merge with a simulated detector on nuScenes: merge and evaluate"):
        pred = ws.predictions("nuscenes-boxmerge")
        box_merge_nuscenes_run(
            ws.nuscenes, steps.NUS_VERSION, eval_set, centres, ws.work / "nuscenes-boxes", pred,
            seed=size.seed,
        )  # fmt: skip
        semantics = "ground truth (simulated regression)"
        notes = BOX_MERGE_NOTE.format(seed=size.seed, semantics=semantics)
        meta = _meta("Box-merge (simulated detector)", eval_set, data, notes)
        _evaluate(ws, eval_set, pred, "nuscenes-boxmerge", meta, workers, result)
