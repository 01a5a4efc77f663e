"""panoptic-bench: LiDAR panoptic segmentation toolkit.

Exact SemanticKITTI / Panoptic nuScenes scoring, nuScenes panoptic label generation,
DS-Net and its clustering / box-merge baselines in pure PyTorch, and the paper's
tables and figures.
"""

__version__ = "0.1.0"
