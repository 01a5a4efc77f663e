"""DS-Net inference: per-scan prediction, clusterers and the ``infer`` command runner."""
