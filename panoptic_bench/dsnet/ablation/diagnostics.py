"""Per-seed dynamic-shifting diagnostics of the default ablation variant → Figs. 5, 6 and 7.

Per validation scan, ``RUN_DIR/dynamic_shift/<seq>_<frame>.npz`` keeps ``seed_index`` (M',
indices into the predicted things points), ``positions`` (I + 1, M', 3) trajectories,
``weights`` (I, M', l), implied ``bandwidths`` (I, M') = Σ_j W_j δ_j, ``seed_labels`` and the
``candidates`` δ (l,). From them (through :mod:`panoptic_bench.reports.inputs`):

- Fig. 5 (``analysis.json`` ``learned_bandwidth``): per ground-truth things class, the mean
  implied bandwidth of the first iteration over the seeds on that class's points, against the
  class's mean instance size = 2 × mean distance of an instance's regressed centres from their
  mean (instances with at least ``MIN_SIZE_POINTS`` points);
- Fig. 7 (``bandwidth_per_iteration``): the same mean bandwidth at every iteration, with the
  smallest candidate as lower limit;
- Fig. 6 (``shift_iterations.npz``): the first scan's seeds before and after every iteration,
  coloured by the bandwidth each uses next (the last panel repeats the last iteration's).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from panoptic_bench.dsnet.ablation.cache import EvalScan

__all__ = ["Diagnostics", "MIN_SIZE_POINTS"]

#: Smallest ground-truth instance counted in the class sizes of Fig. 5.
MIN_SIZE_POINTS = 10


class Diagnostics:
    """Accumulates per-class bandwidth statistics over the scans of one DS run.

    Parameters
    ----------
    candidates : sequence of float
        Bandwidth candidates δ_j (m) of the module (lower limit of Fig. 7).
    """

    def __init__(self, candidates: Sequence[float]) -> None:
        self.candidates = np.asarray(candidates, dtype=np.float32)
        self.bw_sum: dict[int, np.ndarray] = {}
        self.bw_count: dict[int, int] = {}
        self.sizes: dict[int, list[float]] = {}
        self.fig6_written = False

    def add(self, run_dir: Path, scan: EvalScan, diag) -> None:
        """Record one scan's :class:`~panoptic_bench.dsnet.model.ds_head.ShiftDiagnostics`."""
        from panoptic_bench.io import write_npz
        from panoptic_bench.reports.inputs import write_shift_iterations

        seq, frame = scan.key
        arrays = diag.as_arrays()
        write_npz(
            Path(run_dir) / "dynamic_shift" / f"{seq}_{frame}.npz",
            candidates=self.candidates,
            **arrays,
        )
        bw = np.asarray(diag.bandwidths, dtype=np.float64)  # (I, M')
        if bw.size == 0:
            return
        if not self.fig6_written:
            panels = np.concatenate([bw, bw[-1:]], axis=0)
            write_shift_iterations(run_dir, scan.xyz[scan.things], diag.positions, panels)
            self.fig6_written = True
        point = scan.things[diag.seed_index]
        cls = scan.gt_sem[point]
        on_instance = scan.gt_inst[point] > 0
        for c in np.unique(cls[on_instance]):
            sel = on_instance & (cls == c)
            self.bw_sum[int(c)] = self.bw_sum.get(int(c), 0.0) + bw[:, sel].sum(axis=1)
            self.bw_count[int(c)] = self.bw_count.get(int(c), 0) + int(sel.sum())
        centres = scan.xyz.astype(np.float64) + scan.offsets
        for inst in np.unique(scan.gt_inst[scan.gt_inst > 0]):
            pts = np.flatnonzero(scan.gt_inst == inst)
            if len(pts) < MIN_SIZE_POINTS:
                continue
            c = centres[pts]
            size = 2.0 * float(np.linalg.norm(c - c.mean(axis=0), axis=1).mean())
            self.sizes.setdefault(int(scan.gt_sem[pts[0]]), []).append(size)

    def analysis(self) -> dict:
        """``analysis.json`` sections ``learned_bandwidth`` and ``bandwidth_per_iteration``."""
        from panoptic_bench.datasets.semantickitti import LABELS

        names = LABELS.class_names
        mean_bw = {c: self.bw_sum[c] / self.bw_count[c] for c in sorted(self.bw_count)}
        per_iter = {names[c]: [float(v) for v in bw] for c, bw in mean_bw.items()}
        out: dict = {}
        if per_iter:
            out["bandwidth_per_iteration"] = {
                "bandwidth_m": per_iter,
                "lower_limit": float(self.candidates.min()),
            }
        both = [c for c in mean_bw if c in self.sizes]
        if both:
            out["learned_bandwidth"] = {
                "size_m": {names[c]: float(np.mean(self.sizes[c])) for c in both},
                "bandwidth_m": {names[c]: float(mean_bw[c][0]) for c in both},
            }
        return out

    def write(self, run_dir: Path) -> Path | None:
        """Write ``run_dir/analysis.json`` (nothing when no seed lay on a things instance)."""
        from panoptic_bench.reports.inputs import write_analysis

        sections = self.analysis()
        return write_analysis(run_dir, **sections) if sections else None
