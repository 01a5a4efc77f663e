"""SemanticKITTI format: packaged label facts vs the official file, readers, writers, listing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from panoptic_bench.datasets import semantickitti as sk
from panoptic_bench.errors import InputError


@pytest.fixture(scope="module")
def official(shared_data: Path) -> dict:
    with open(shared_data / "semantic-kitti.yaml") as fh:
        return yaml.safe_load(fh)


def test_packaged_facts_match_official_file(official: dict) -> None:
    labels = sk.LABELS
    assert labels.raw_names == official["labels"]
    assert labels.learning_map == official["learning_map"]
    assert labels.learning_map_inv == official["learning_map_inv"]
    assert labels.color_map == {k: tuple(v) for k, v in official["color_map"].items()}
    assert labels.splits == official["split"]
    ignored = tuple(k for k, v in official["learning_ignore"].items() if v)
    assert labels.ignore_ids == ignored == (0,)
    names = tuple(official["labels"][official["learning_map_inv"][i]] for i in range(20))
    assert labels.class_names == names
    assert labels.class_names[0] == "unlabeled" and len(labels.class_names) == 20


def test_things_and_stuff() -> None:
    names = sk.LABELS.class_names
    things = {names[i] for i in sk.LABELS.thing_ids}
    assert sk.LABELS.thing_ids == tuple(range(1, 9))
    assert sk.LABELS.stuff_ids == tuple(range(9, 20))
    assert things == {
        "car",
        "bicycle",
        "motorcycle",
        "truck",
        "other-vehicle",
        "person",
        "bicyclist",
        "motorcyclist",
    }
    assert sk.LABELS.splits["valid"] == [8]
    assert sk.LABELS.splits["train"] == [0, 1, 2, 3, 4, 5, 6, 7, 9, 10]
    assert sk.LABELS.splits["test"] == list(range(11, 22))


def test_luts(official: dict) -> None:
    lut = sk.LABELS.train_lut
    assert lut.dtype == np.uint8 and lut.shape == (65536,)
    for raw, train in official["learning_map"].items():
        assert lut[raw] == train
    assert lut[2] == 0 and lut[65535] == 0  # unknown -> 0
    assert sk.LABELS.valid_raw.dtype == bool and sk.LABELS.valid_raw.sum() == len(
        official["labels"]
    )
    assert sk.LABELS.inv_lut.dtype == np.uint16 and sk.LABELS.inv_lut.shape == (20,)
    assert not lut.flags.writeable


def test_label_arithmetic_round_trip() -> None:
    rng = np.random.default_rng(0)
    raw = rng.choice(list(sk.LABELS.raw_names), 1000).astype(np.uint16)
    inst = rng.integers(0, 65536, 1000).astype(np.uint16)
    label = sk.make_label(raw, inst)
    assert label.dtype == np.uint32
    sem2, inst2 = sk.split_label(label)
    assert sem2.dtype == np.uint16 and inst2.dtype == np.uint16
    np.testing.assert_array_equal(sem2, raw)
    np.testing.assert_array_equal(inst2, inst)
    train = sk.to_train(raw)
    assert train.dtype == np.uint8
    np.testing.assert_array_equal(sk.to_train(label), train)  # full labels accepted
    back = sk.to_raw(train)
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(sk.to_train(back), train)
    assert sk.to_train(np.array([252, 10, 60, 1]))[:4].tolist() == [1, 1, 9, 0]
    with pytest.raises(ValueError):
        sk.to_raw(np.array([20]))
    with pytest.raises(ValueError):
        sk.make_label(np.array([70000]), np.array([0]))


def test_read_real_scans(kitti_root: Path) -> None:
    refs = sk.list_scans(kitti_root)
    assert [(r.sequence, r.frame) for r in refs] == [("00", f"00000{i}") for i in range(3)]
    assert sk.list_scans(kitti_root, sequences=[0]) == refs
    for ref in refs:
        pts = sk.read_scan(ref.scan)
        lab = sk.read_labels(ref.label)
        assert pts.dtype == np.float32 and pts.shape[1] == 4
        assert lab.dtype == np.uint32 and lab.shape == (pts.shape[0],)
        assert sk.LABELS.valid_raw[lab & 0xFFFF].all()
    assert sk.prediction_path("/p", refs[0]) == Path("/p/sequences/00/predictions/000000.label")


def test_write_read_round_trip(tmp_path: Path) -> None:
    pts = np.arange(40, dtype=np.float32).reshape(10, 4)
    lab = np.arange(10, dtype=np.uint32) * 65537
    sk.write_scan(tmp_path / "a" / "x.bin", pts)
    sk.write_labels(tmp_path / "a" / "x.label", lab)
    np.testing.assert_array_equal(sk.read_scan(tmp_path / "a" / "x.bin"), pts)
    np.testing.assert_array_equal(sk.read_labels(tmp_path / "a" / "x.label"), lab)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["x.bin", "x.label"]


def test_bad_files(tmp_path: Path) -> None:
    (tmp_path / "bad.label").write_bytes(b"123")
    (tmp_path / "bad.bin").write_bytes(b"\0" * 20)
    with pytest.raises(InputError, match="multiple of 4") as err:
        sk.read_labels(tmp_path / "bad.label")
    assert err.value.path == tmp_path / "bad.label"
    with pytest.raises(InputError, match="multiple of 16"):
        sk.read_scan(tmp_path / "bad.bin")
    with pytest.raises(InputError, match="not found"):
        sk.read_labels(tmp_path / "missing.label")
    with pytest.raises(InputError, match="not found"):
        sk.list_scans(tmp_path)
    with pytest.raises(InputError, match="unknown split"):
        sk.list_scans(tmp_path, split="nope")
    (tmp_path / "sequences" / "03" / "velodyne").mkdir(parents=True)
    with pytest.raises(InputError, match="empty sequence"):
        sk.list_scans(tmp_path, sequences=["3"])
