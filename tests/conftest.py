"""Shared test fixtures: the real data in ../shared/data (always present in CI)."""

from __future__ import annotations

import os
from pathlib import Path

# One intra-op thread per test process: the suite's tensors are tiny, and on a 2-core machine
# OpenMP spinning threads turn milliseconds into seconds when the other core is busy.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "2")

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Root of ../shared/data; its absence is a failure, never a skip."""
    assert SHARED_DATA.is_dir(), f"real test data missing: {SHARED_DATA}"
    return SHARED_DATA


@pytest.fixture(scope="session")
def kitti_root(shared_data: Path) -> Path:
    """SemanticKITTI-format root with sequences/00 (3 real labelled scans)."""
    return shared_data / "semantickitti"


@pytest.fixture
def one_torch_thread():
    """Run a test on one torch intra-op thread (training tests: reproducible and fast)."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="session")
def hostile_kitti(tmp_path_factory) -> dict:
    """Tiny SemanticKITTI world of the hostile-input suite (tests/hostile_world.py); read only."""
    from hostile_world import kitti_world

    return kitti_world(tmp_path_factory.mktemp("hostile-kitti"))


@pytest.fixture(scope="session")
def hostile_nuscenes(tmp_path_factory) -> dict:
    """Tiny nuScenes dataroot with labels and perfect predictions (tests/hostile_world.py)."""
    from hostile_world import nuscenes_world

    return nuscenes_world(tmp_path_factory.mktemp("hostile-nus"))
