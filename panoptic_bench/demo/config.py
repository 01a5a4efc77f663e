"""Sizes and method settings of the demo (frozen dataclasses, strict ``from_dict`` / ``to_dict``).

:data:`FULL` is what ``panoptic-bench demo`` runs, :data:`QUICK` what ``--quick`` runs and
:data:`TINY` what the tests run; all three go through the same step functions.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

__all__ = [
    "CLUSTERINGS",
    "FULL",
    "QUICK",
    "TINY",
    "ClusteringSpec",
    "DemoSize",
]


@dataclass(frozen=True)
class DemoSize:
    """How much synthetic data the demo makes and uses.

    Attributes
    ----------
    train_frames, val_frames : int
        Frames of the SemanticKITTI-format training sequence ``00`` and validation sequence
        ``08`` (10 Hz HDL-64E scans, about 120k points each).
    nus_scenes, nus_samples : int
        Scenes and keyframes per scene of the nuScenes-format ``v1.0-mini`` dataroot. Scenes
        alternate between ``mini_train`` and ``mini_val``; ``mini_val`` has two scenes, so at
        least 4 scenes are needed to evaluate it.
    bandwidth_scans : int
        Validation scans used for the Fig. 3b mean-shift bandwidth sweep.
    seed : int
        Global seed of the synthetic world and of the simulated regression.
    """

    train_frames: int = 20
    val_frames: int = 40
    nus_scenes: int = 4
    nus_samples: int = 10
    bandwidth_scans: int = 20
    seed: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name != "seed" and getattr(self, f.name) < 1:
                raise ValueError(f"{f.name} must be >= 1, got {getattr(self, f.name)}")
        if self.nus_scenes < 4:
            raise ValueError("nus_scenes must be >= 4 (mini_val needs scenes 2 and 4)")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DemoSize:
        """Build from a mapping; unknown keys are an error."""
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"unknown demo size keys: {unknown}")
        return cls(**{k: int(v) for k, v in data.items()})

    def to_dict(self) -> dict[str, int]:
        """Plain mapping of the fields."""
        return asdict(self)


FULL = DemoSize()
QUICK = DemoSize(train_frames=4, val_frames=10, nus_scenes=4, nus_samples=3, bandwidth_scans=5)
TINY = DemoSize(train_frames=1, val_frames=2, nus_scenes=4, nus_samples=1, bandwidth_scans=1)


@dataclass(frozen=True)
class ClusteringSpec:
    """One heuristic clustering of the regressed centres.

    Attributes
    ----------
    key : str
        Short name used in run directory names (``bfs``).
    label : str
        Display name (``BFS``; the Fig. 4b bar label).
    method : str
        :class:`panoptic_bench.baselines.clustering.Method` value.
    params : tuple of (str, value) pairs
        Keyword arguments of the estimator.
    """

    key: str
    label: str
    method: str
    params: tuple[tuple[str, Any], ...]

    def make(self) -> Any:
        """The estimator (see :func:`panoptic_bench.baselines.clustering.make_clusterer`)."""
        from panoptic_bench.baselines.clustering import make_clusterer

        return make_clusterer(self.method, **dict(self.params))

    def describe(self) -> str:
        """``"BFS (radius 1.2)"``."""
        args = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in self.params)
        return f"{self.label} ({args})" if args else self.label

    def cli_args(self) -> str:
        """The same clustering as ``panoptic-bench cluster`` options."""
        out = [f"--method {self.method}"]
        for k, v in self.params:
            out.append(f"--{k.replace('_', '-')}" + ("" if v is True else f" {v}"))
        return " ".join(out)


#: The four heuristic clusterings of the paper's Fig. 4b, on the same regressed centres.
#: BFS radius 1.2 m is the paper's nuScenes BFS radius, mean shift 1.2 m the backbone bandwidth
#: (bin seeding as in DS-Net's code); DBSCAN/HDBSCAN use their libraries' defaults.
CLUSTERINGS: tuple[ClusteringSpec, ...] = (
    ClusteringSpec("bfs", "BFS", "bfs", (("radius", 1.2),)),
    ClusteringSpec("dbscan", "DBSCAN", "dbscan", (("eps", 0.5), ("min_samples", 5))),
    ClusteringSpec("hdbscan", "HDBSCAN", "hdbscan", (("min_cluster_size", 5),)),
    ClusteringSpec(
        "meanshift", "Mean Shift", "meanshift", (("bandwidth", 1.2), ("bin_seeding", True))
    ),
)
