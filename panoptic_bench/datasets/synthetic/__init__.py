"""Synthetic ray-cast LiDAR world: procedural streets scanned by HDL-64E / HDL-32E models.

Library entry points (the CLI ``panoptic-bench synth ...`` calls these):

- :func:`generate_semantickitti` writes sequences in the SemanticKITTI layout;
- :func:`generate_nuscenes` writes a nuScenes dataroot that the devkit loads;
- :class:`Sequence` simulates frames in memory (``Sequence(seed, key, n_frames)``);
- :func:`~panoptic_bench.datasets.synthetic.stats.compare` measures realism against real scans.
"""

from panoptic_bench.datasets.synthetic.sensor import HDL32E, HDL64E, LidarModel
from panoptic_bench.datasets.synthetic.sequence import Frame, Sequence
from panoptic_bench.datasets.synthetic.writers import generate_nuscenes, generate_semantickitti

__all__ = [
    "HDL32E",
    "HDL64E",
    "Frame",
    "LidarModel",
    "Sequence",
    "generate_nuscenes",
    "generate_semantickitti",
]
