"""nuScenes-format writer and reader: the devkit loads what we write, frames are right, errors are clear."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from nuscenes_world import make_scene, real_sweep, tree_bytes, write_mini
from pyquaternion import Quaternion

from panoptic_bench.datasets.nuscenes import scene_names, token, write_dataset
from panoptic_bench.datasets.nuscenes_reader import NuScenesLidar, open_nuscenes
from panoptic_bench.errors import InputError

VERSION = "v1.0-mini"


@pytest.fixture(scope="module")
def mini(tmp_path_factory, shared_data) -> Path:
    return write_mini(tmp_path_factory.mktemp("nus") / "root", real_sweep(shared_data))


@pytest.fixture(scope="module")
def nusc(mini):
    from nuscenes import NuScenes

    return NuScenes(VERSION, str(mini), verbose=False)


def test_devkit_loads_all_tables(nusc, shared_data):
    assert len(nusc.scene) == 4 and len(nusc.sample) == 11
    assert len(nusc.lidarseg) == len(nusc.sample_data) == 11
    assert {c["index"] for c in nusc.category} == set(range(32))
    assert nusc.lidarseg_name2idx_mapping["vehicle.car"] == 17
    # the first scene uses the real sweep
    sd = nusc.get("sample_data", nusc.sample[0]["data"]["LIDAR_TOP"])
    pts = np.fromfile(Path(nusc.dataroot) / sd["filename"], np.float32).reshape(-1, 5)
    real = np.fromfile(real_sweep(shared_data), np.float32).reshape(-1, 5)
    assert len(real) == 34688 and len(pts) > len(real)
    assert np.array_equal(pts[-len(real) :, :3], real[:, :3])


def test_links_and_instances(nusc):
    for scene in nusc.scene:
        tok, seen = scene["first_sample_token"], 0
        while tok:
            s = nusc.get("sample", tok)
            seen += 1
            if s["next"]:
                assert nusc.get("sample", s["next"])["prev"] == tok
            tok = s["next"]
        assert seen == scene["nbr_samples"]
    for inst in nusc.instance:
        tok, n = inst["first_annotation_token"], 0
        while tok:
            ann = nusc.get("sample_annotation", tok)
            assert ann["instance_token"] == inst["token"]
            n, last, tok = n + 1, tok, ann["next"]
        assert n == inst["nbr_annotations"] and last == inst["last_annotation_token"]
    assert max(i["nbr_annotations"] for i in nusc.instance) >= 3  # recurring instances


def test_boxes_come_back_in_sensor_frame(nusc):
    scene = make_scene("scene-0103", seed=0, n_samples=2)
    for i, spec in enumerate(scene.samples):
        assert abs(Quaternion(spec.ego_rotation).degrees) > 1
        sample = nusc.get("sample", nusc.scene[0]["first_sample_token"])
        if i:
            sample = nusc.get("sample", sample["next"])
        _, boxes, _ = nusc.get_sample_data(sample["data"]["LIDAR_TOP"])
        assert len(boxes) == len(spec.boxes)
        car_a = boxes[0]
        ann = nusc.get("sample_annotation", car_a.token)
        assert ann["instance_token"] == token("instance", "scene-0103/car-a")
        # car-a was built at (8, 3, -0.75) + shift in the sensor frame, axis-aligned there
        np.testing.assert_allclose(car_a.center, [8.0 + 0.5 * i, 3.0, -0.75], atol=1e-9)
        np.testing.assert_allclose(car_a.orientation.rotation_matrix, np.eye(3), atol=1e-9)
        np.testing.assert_allclose(car_a.wlh, [1.875, 4.5, 1.625])


def test_num_lidar_pts_counts_points_in_box(nusc):
    from nuscenes.utils.geometry_utils import points_in_box

    for sample in nusc.sample[:4]:
        sd = sample["data"]["LIDAR_TOP"]
        path, boxes, _ = nusc.get_sample_data(sd)
        pts = np.fromfile(path, np.float32).reshape(-1, 5)[:, :3].T
        for box in boxes:
            ann = nusc.get("sample_annotation", box.token)
            assert ann["num_lidar_pts"] == points_in_box(box, pts).sum() > 0


def test_writing_is_deterministic_and_replaces(tmp_path):
    scenes = [make_scene("scene-0103", 0, 2), make_scene("scene-0916", 1, 2)]
    write_dataset(tmp_path / "a", VERSION, scenes)
    write_dataset(tmp_path / "b", VERSION, scenes)
    assert tree_bytes(tmp_path / "a") == tree_bytes(tmp_path / "b")
    write_dataset(tmp_path / "a", VERSION, scenes[:1])  # rewrite: tables and lidarseg replaced
    assert len(json.loads((tmp_path / "a" / VERSION / "scene.json").read_text())) == 1
    assert len(list((tmp_path / "a" / "lidarseg" / VERSION).iterdir())) == 2
    assert not [p for p in (tmp_path / "a").iterdir() if p.name.startswith(".")]
    open_nuscenes(tmp_path / "a", VERSION)


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda s: setattr(s, "name", "scene-0001"), "not a scene name"),
        (lambda s: setattr(s.samples[0], "lidarseg", s.samples[0].lidarseg[:-1]), "lidarseg"),
        (lambda s: setattr(s.samples[1], "timestamp", s.samples[0].timestamp), "timestamps"),
    ],
)
def test_writer_rejects_bad_specs(tmp_path, mutate, match):
    scene = make_scene("scene-0103", 0, 2)
    mutate(scene)
    with pytest.raises(InputError, match=match):
        write_dataset(tmp_path / "r", VERSION, [scene])
    assert not (tmp_path / "r").exists()


def test_scene_names():
    assert scene_names(VERSION, "mini_val") == ["scene-0103", "scene-0916"]
    assert len(scene_names("v1.0-trainval", "val")) == 150
    with pytest.raises(InputError, match="does not belong"):
        scene_names(VERSION, "val")
    with pytest.raises(InputError, match="unknown nuScenes split"):
        scene_names(VERSION, "nope")


def test_reader_lists_eval_set_like_devkit(mini, nusc):
    from nuscenes.eval.lidarseg.utils import get_samples_in_eval_set

    reader = NuScenesLidar(mini, VERSION)
    expected = [
        nusc.get("sample", t)["data"]["LIDAR_TOP"]
        for t in get_samples_in_eval_set(nusc, "mini_val")
    ]
    assert reader.sample_data_tokens("mini_val") == expected
    assert reader.sample_data_tokens() == [s["data"]["LIDAR_TOP"] for s in nusc.sample]
    tok = expected[0]
    pts, seg = reader.load_points(tok), reader.load_lidarseg(tok)
    assert pts.dtype == np.float32 and pts.shape == (len(seg), 5) and seg.dtype == np.uint8
    with pytest.raises(InputError, match="absent from the dataroot"):
        reader.sample_data_tokens("mini_train")
    with pytest.raises(InputError, match="no panoptic table"):
        reader.load_panoptic(tok)


def _copy(mini: Path, tmp_path: Path) -> Path:
    root = tmp_path / "copy"
    shutil.copytree(mini, root)
    return root


def test_reader_errors(mini, tmp_path):
    root = _copy(mini, tmp_path)
    with pytest.raises(InputError, match="unknown version folder 'v1.0-trainval'.*v1.0-mini"):
        open_nuscenes(root, "v1.0-trainval")
    rows = json.loads((root / VERSION / "lidarseg.json").read_text())
    victim = root / rows[3]["filename"]
    victim.write_bytes(victim.read_bytes()[:-1])
    reader = NuScenesLidar(root, VERSION)
    with pytest.raises(InputError, match=f"sample_data {rows[3]['token']} has") as exc:
        reader.load_lidarseg(rows[3]["token"])
    assert str(victim) in str(exc.value)
    victim.unlink()
    with pytest.raises(InputError, match="lidarseg file of sample_data .* is missing") as exc:
        open_nuscenes(root, VERSION)
    assert str(victim) in str(exc.value)
