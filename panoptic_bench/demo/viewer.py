"""The demo's viewer inputs: best and worst scan by PQ of its headline SemanticKITTI run.

The headline run is DS-Net when the shipped checkpoint ran (its prediction root also holds the
regressed centres), else mean shift on the simulated regression. The report turns the run's
``viewer_scans.npz`` into ``viewer/<run>.html`` (see :mod:`panoptic_bench.viewer.report`).
"""

from __future__ import annotations

from pathlib import Path

from panoptic_bench.demo.config import CLUSTERINGS

__all__ = ["write_demo_viewer"]


def write_demo_viewer(ws, target, runs: list[Path]) -> Path | None:
    """Write ``viewer_scans.npz`` into the headline run of ``target``; None if it did not run.

    Parameters
    ----------
    ws : panoptic_bench.demo.steps.Workspace
    target : panoptic_bench.demo.kitti.KittiTarget
    runs : list of Path
        The run directories the demo produced.
    """
    from panoptic_bench.viewer.report import write_best_and_worst

    dsnet = ws.runs / f"{target.prefix}-dsnet"
    if dsnet in runs:
        run, pred = dsnet, ws.predictions(f"{target.prefix}-dsnet")
        centres = pred
    else:
        key = next(s.key for s in CLUSTERINGS if s.method == "meanshift")
        run, pred = ws.runs / f"{target.prefix}-{key}", ws.predictions(f"{target.prefix}-{key}")
        centres = ws.centres(f"{target.prefix}-simulated")
        if run not in runs:
            return None
    if not any((centres / "sequences").glob("*/centers/*.npz")):
        centres = None
    return write_best_and_worst(run, target.dataset, pred, target.sequences, centers=centres)
