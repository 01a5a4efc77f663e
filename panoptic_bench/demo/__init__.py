"""The demo: the whole job on the embedded default, and the committed report sets.

- :func:`~panoptic_bench.demo.pipeline.run_demo`: synthetic SemanticKITTI + nuScenes data →
  labels → regressed centres (DS-Net checkpoint or simulated regression) → four clusterings →
  evaluation → report (``panoptic-bench demo``);
- :func:`~panoptic_bench.demo.real.run_real_scans`: the same on the real scans of
  ``../shared/data`` (``panoptic-bench demo --real-scans ROOT``).

Every stage is a small function of :mod:`panoptic_bench.demo.steps`,
:mod:`~panoptic_bench.demo.evaluate` and :mod:`~panoptic_bench.demo.analysis`; the sizes are in
:mod:`~panoptic_bench.demo.config`. Nothing runs at import.
"""
