"""The machine a training ran on (training/platform.py): records, the change note, bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from panoptic_bench.dsnet.training.platform import (
    NUMERIC_KEYS,
    PLATFORM_FILE,
    platform_record,
    read_records,
    record_platform,
)
from panoptic_bench.errors import InputError


def test_record_names_this_process():
    rec = platform_record("cpu")
    assert rec["torch"] == torch.__version__
    assert rec["numpy"] == np.__version__
    assert rec["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert rec["threads"] == torch.get_num_threads()
    assert rec["device"] == "cpu"
    assert set(NUMERIC_KEYS) <= set(rec)
    assert all(isinstance(rec[k], str) and rec[k] for k in ("cpu", "python", "started"))


def test_records_append_and_one_machine_gives_no_note(tmp_path: Path):
    assert read_records(tmp_path) == []
    assert record_platform(tmp_path, "cpu") is None
    assert record_platform(tmp_path, torch.device("cpu")) is None
    records = json.loads((tmp_path / PLATFORM_FILE).read_text())
    assert len(records) == 2 and records == read_records(tmp_path)


def test_a_changed_kernel_kind_or_thread_count_is_named(tmp_path: Path):
    record_platform(tmp_path, "cpu")
    path = tmp_path / PLATFORM_FILE
    records = json.loads(path.read_text())
    records[-1]["torch_cpu_capability"] = "SOMETHING_ELSE"
    records[-1]["threads"] = records[-1]["threads"] + 3
    path.write_text(json.dumps(records))
    note = record_platform(tmp_path, "cpu")
    assert note is not None
    assert "torch_cpu_capability: 'SOMETHING_ELSE' -> " in note
    assert f"threads: {records[-1]['threads']} -> {torch.get_num_threads()}" in note
    assert "cpu:" not in note.replace("torch_cpu_capability", "")  # unchanged keys are not named
    # the note compares with the previous call, which now is this machine again
    assert record_platform(tmp_path, "cpu") is None
    assert len(read_records(tmp_path)) == 3


@pytest.mark.parametrize("text", ["{not json", '{"a": 1}', "[1, 2]"])
def test_a_bad_records_file_names_itself(tmp_path: Path, text: str):
    (tmp_path / PLATFORM_FILE).write_text(text)
    with pytest.raises(InputError, match="delete the file") as err:
        record_platform(tmp_path, "cpu")
    assert PLATFORM_FILE in str(err.value)
    assert (tmp_path / PLATFORM_FILE).read_text() == text  # left as it was
