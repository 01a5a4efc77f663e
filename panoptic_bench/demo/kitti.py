"""The methods of the demo on a SemanticKITTI-format tree (synthetic world or real scans).

Regressed centres come from the shipped DS-Net checkpoint when there is one (the DS-Net row,
and the four clusterings on the backbone's centres, plus "Backbone" without fusion for Fig. 4a);
otherwise from the *simulated regression* of the baselines, labelled so in every row.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from panoptic_bench.demo import steps
from panoptic_bench.demo.boxmerge import BOX_MERGE_NOTE, box_merge_semantickitti_run
from panoptic_bench.demo.config import CLUSTERINGS, ClusteringSpec
from panoptic_bench.demo.evaluate import evaluate_semantickitti_run

__all__ = [
    "DSNET_CHECKPOINT",
    "REAL_CHECKPOINT",
    "SIMULATED_NOTE",
    "DemoResult",
    "KittiTarget",
    "run_kitti_methods",
]

DSNET_CHECKPOINT = "dsnet_synthetic.pt"
REAL_CHECKPOINT = "dsnet_semantickitti_cpu.pt"  # default of --real-scans when shipped
SIMULATED_NOTE = (
    "simulated regression, not a network result: semantics = ground truth, centres = "
    "ground-truth box centres + noise along the viewing ray (panoptic_bench.baselines."
    "regression, seed {seed})"
)


@dataclass
class DemoResult:
    """What a demo run produced.

    Attributes
    ----------
    index : Path
        ``DIR/index.md``.
    runs : list of Path
        Run directories, in report order.
    regression : str
        Source of the SemanticKITTI regressed centres (``DS-Net`` or ``simulated regression``).
    missing : list of str
        Pipeline pieces that were not available and were left out.
    summary : str
        The terminal summary table.
    """

    index: Path
    runs: list[Path]
    regression: str = "simulated regression"
    missing: list[str] = field(default_factory=list)
    summary: str = ""


@dataclass(frozen=True)
class KittiTarget:
    """One SemanticKITTI-format tree to run the methods on.

    Attributes
    ----------
    dataset : Path
        Root holding ``sequences/XX/{velodyne,labels}``.
    sequences : tuple of str
        Sequences to predict and score.
    data : str
        What the numbers are computed on (the Data column of the tables).
    prefix : str
        Run directory prefix (``semantickitti`` → ``runs/semantickitti-bfs``).
    seed : int
        Seed of the simulated regression.
    bandwidth_scans : int
        Scans of the Fig. 3b bandwidth sweep.
    split : str
        ``run.json`` split (``val``: compared with the paper's Table 1).
    checkpoint : Path, optional
        DS-Net checkpoint to run; None = the shipped ``DSNET_CHECKPOINT`` when there is one.
    per_sequence : bool
        Also score the DS-Net predictions of each sequence on its own (one row each).
    """

    dataset: Path
    sequences: tuple[str, ...]
    data: str
    prefix: str
    seed: int = 0
    bandwidth_scans: int = 5
    split: str = "val"
    checkpoint: Path | None = None
    per_sequence: bool = False


def _meta(target: KittiTarget, method: str, notes: str, ablation: dict) -> dict:
    return {
        "method": method,
        "dataset": "semantickitti",
        "split": target.split,
        "data": target.data,
        "notes": notes,
        "ablation": ablation,
    }


def _dsnet(ws, target: KittiTarget, stages, result: DemoResult, workers: int) -> Path | None:
    """DS-Net row from the target's (or the shipped) checkpoint; returns the prediction root."""
    ckpt = target.checkpoint or steps.find_checkpoint(DSNET_CHECKPOINT)
    if ckpt is None:
        result.missing.append(
            f"DS-Net: no shipped checkpoint panoptic_bench/checkpoints/{DSNET_CHECKPOINT} "
            "(or its network code); the clusterings use the simulated regression"
        )
        return None
    shown = steps.checkpoint_label(ckpt)
    with stages(f"DS-Net inference ({shown}, CPU)"):
        pred = ws.predictions(f"{target.prefix}-dsnet")
        method = steps.dsnet_regression(ckpt, target.dataset, target.sequences, pred)
    with stages(f"evaluate {method}"):
        ablation = {"clustering": "Dynamic Shifting"}
        if method.startswith("DS-Net"):
            ablation["framework"] = "+ DS"
        note = f"checkpoint {shown}, CPU inference" + steps.training_overlap_note(
            ckpt, target.sequences
        )
        run = ws.runs / f"{target.prefix}-dsnet"
        evaluate_semantickitti_run(
            target.dataset, pred, target.sequences, run, _meta(target, method, note, ablation),
            workers=workers, show=ws.show,
        )  # fmt: skip
        result.runs.append(run)
    if target.per_sequence and len(target.sequences) > 1:
        from panoptic_bench.datasets.semantickitti import list_scans

        for seq in target.sequences:
            with stages(f"evaluate {method}, sequence {seq}"):
                run = ws.runs / f"{target.prefix}-dsnet-seq{seq}"
                meta = _meta(target, f"{method} (seq {seq})", note, {})
                n = len(list_scans(target.dataset, sequences=[seq]))
                meta["data"] = f"{n} real SemanticKITTI scans, seq {seq}"
                evaluate_semantickitti_run(
                    target.dataset, pred, (seq,), run, meta, workers=workers, show=ws.show
                )
                result.runs.append(run)
    result.regression = "DS-Net"
    return pred


def _variants(network: bool) -> list[tuple[ClusteringSpec, bool]]:
    variants = [(spec, True) for spec in CLUSTERINGS]
    if network:  # Fig. 4a: the backbone alone, without consensus fusion
        variants.append((CLUSTERINGS[-1], False))
    return variants


def _labels(spec: ClusteringSpec, fusion: bool, network: bool) -> tuple[str, dict]:
    """Method label and Fig. 4a/4b bars of one clustering run."""
    if not network:
        return f"{spec.label} (simulated regression)", {"clustering": spec.label}
    if spec.method == "meanshift":
        if fusion:
            return "Backbone with Fusion", {"clustering": spec.label, "framework": "+ fusion"}
        return "Backbone", {"framework": "Backbone"}
    return f"Backbone + {spec.label}", {"clustering": spec.label}


def run_kitti_methods(
    ws: steps.Workspace,
    target: KittiTarget,
    stages,
    result: DemoResult,
    workers: int = 1,
    use_checkpoint: bool = True,
) -> None:
    """Regression, the four clusterings, box-merge and their evaluation; appends run dirs.

    The mean-shift run also gets the Fig. 3a/3b inputs (``analysis.json``) and a bird's-eye
    view (``bev.npz``) of the first scan.
    """
    pred_root = _dsnet(ws, target, stages, result, workers) if use_checkpoint else None
    network = pred_root is not None
    if network:
        centres, source = pred_root, "DS-Net backbone regression"
    else:
        centres = ws.centres(f"{target.prefix}-simulated")
        source = SIMULATED_NOTE.format(seed=target.seed)
        with stages("simulated regression (SemanticKITTI format, not a network result)"):
            steps.simulate_semantickitti_centres(
                target.dataset, target.sequences, centres, seed=target.seed, workers=workers
            )
    figure_run = None
    for spec, fusion in _variants(network):
        key = spec.key if fusion else f"{spec.key}-nofusion"
        pred = ws.predictions(f"{target.prefix}-{key}")
        with stages(f"{spec.describe()}{'' if fusion else ', no fusion'}: cluster and evaluate"):
            steps.cluster_semantickitti_centres(
                target.dataset, centres, target.sequences, pred, spec, fusion=fusion,
                workers=workers,
            )  # fmt: skip
            method, ablation = _labels(spec, fusion, network)
            notes = f"{source}; clustering {spec.describe()}, min 50 points, " + (
                "consensus fusion" if fusion else "no fusion"
            )
            run = ws.runs / f"{target.prefix}-{key}"
            evaluate_semantickitti_run(
                target.dataset, pred, target.sequences, run,
                _meta(target, method, notes, ablation), workers=workers, show=ws.show,
            )  # fmt: skip
            result.runs.append(run)
        if spec.method == "meanshift" and fusion:
            figure_run = (run, pred)
    with stages("box-merge with a simulated detector: merge and evaluate"):
        pred = ws.predictions(f"{target.prefix}-boxmerge")
        box_merge_semantickitti_run(
            target.dataset, centres, target.sequences, ws.work / f"{target.prefix}-boxes", pred,
            seed=target.seed,
        )  # fmt: skip
        semantics = "backbone prediction" if network else "ground truth (simulated regression)"
        notes = BOX_MERGE_NOTE.format(seed=target.seed, semantics=semantics)
        method = "Box-merge (simulated detector)"
        run = ws.runs / f"{target.prefix}-boxmerge"
        evaluate_semantickitti_run(
            target.dataset, pred, target.sequences, run, _meta(target, method, notes, {}),
            workers=workers, show=ws.show,
        )  # fmt: skip
        result.runs.append(run)
    with stages("Fig. 3a/3b statistics and bird's-eye view"):
        _figure_inputs(target, centres, *figure_run)


def _figure_inputs(target: KittiTarget, centres: Path, run: Path, pred: Path) -> None:
    """``analysis.json`` (Fig. 3a, 3b) and ``bev.npz`` of the first scan for ``run``."""
    from panoptic_bench.datasets.semantickitti import list_scans, prediction_path
    from panoptic_bench.demo import analysis
    from panoptic_bench.reports.inputs import write_analysis

    seqs = target.sequences
    write_analysis(
        run,
        centres_per_voxel=analysis.centres_per_voxel(target.dataset, centres, seqs),
        bandwidth_rq=analysis.bandwidth_rq(
            target.dataset, centres, seqs, max_scans=target.bandwidth_scans
        ),
    )
    ref = list_scans(target.dataset, split=None, sequences=list(seqs))[0]
    analysis.write_bev_scan(run, ref.scan, ref.label, prediction_path(pred, ref))
