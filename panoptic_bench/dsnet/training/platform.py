"""The machine a training ran on (``RUN_DIR/platform.json``) and the note when it changes.

A training is bit-for-bit deterministic for a seed only on one kind of machine. torch picks its
CPU kernels by the processor (``AVX512``, ``AVX2``, ``DEFAULT``), numpy likewise, and the thread
count changes the order of float sums; a last-bit difference then grows over a training's steps
like another seed. Measured on one root, one seed and the same code (sessions 51-52): the first
epoch's loss is 2.34152 with torch's AVX-512 kernels, 2.33808 with its AVX2 kernels, 2.35493 with
its default ones, and 2.3428 with two threads instead of one.

``train`` appends one record per call to ``platform.json``. A call (a ``--resume``, or the next
stage started from the previous one's checkpoint) whose record differs from the directory's
previous record in a key of :data:`NUMERIC_KEYS` is allowed, but :func:`record_platform` returns
a note saying which keys differ: the training goes on, and its checkpoints will not equal those
of a run made on one machine.
"""

from __future__ import annotations

import datetime
import json
import platform
import sys
from pathlib import Path

import numpy as np
import torch

from panoptic_bench.errors import InputError
from panoptic_bench.io import write_json

__all__ = ["NUMERIC_KEYS", "PLATFORM_FILE", "platform_record", "read_records", "record_platform"]

#: File name of the records inside a run directory.
PLATFORM_FILE = "platform.json"
#: Keys whose change between the calls of one run breaks bit-for-bit continuation.
NUMERIC_KEYS = ("torch", "torch_cpu_capability", "numpy", "cpu", "threads", "device")


def _cpu_model() -> str:
    """The processor's model name (``/proc/cpuinfo`` on Linux, else :func:`platform.processor`)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def platform_record(device: torch.device | str) -> dict[str, str | int]:
    """What this process computes with: library versions, kernel kind, processor, threads.

    Parameters
    ----------
    device : torch.device or str
        The training's device (``cpu``, ``cuda:0``, ...).

    Returns
    -------
    dict
        ``started`` (UTC, ISO 8601), ``torch``, ``torch_cpu_capability`` (the kernel kind torch
        dispatches to, e.g. ``AVX512``), ``numpy``, ``python``, ``cpu`` (model name),
        ``threads`` (torch's intra-op threads, int) and ``device``.
    """
    device = torch.device(device)
    if device.type == "cuda":
        dev = f"cuda:{torch.cuda.get_device_name(device)}"
    else:
        dev = device.type
    return {
        "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "torch": torch.__version__,
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "numpy": np.__version__,
        "python": sys.version.split()[0],
        "cpu": _cpu_model(),
        "threads": int(torch.get_num_threads()),
        "device": dev,
    }


def read_records(run_dir: str | Path) -> list[dict]:
    """The records of ``run_dir/platform.json`` ([] when there is none).

    Raises
    ------
    InputError
        The file exists but is not a JSON list of objects.
    """
    path = Path(run_dir) / PLATFORM_FILE
    if not path.is_file():
        return []
    try:
        records = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(
            f"cannot read the run's platform records ({exc}); delete the file to start them again",
            path,
        ) from exc
    if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
        raise InputError(
            "the run's platform records must be a JSON list of objects; delete the file to start "
            "them again",
            path,
        )
    return records


def record_platform(run_dir: str | Path, device: torch.device | str) -> str | None:
    """Append this call's :func:`platform_record` to ``run_dir/platform.json``.

    Returns
    -------
    str or None
        A note naming every key of :data:`NUMERIC_KEYS` whose value differs from the previous
        record's (``key: before -> now``), or None when none does or there is no previous record.
    """
    now = platform_record(device)
    records = read_records(run_dir)
    note = None
    if records:
        last = records[-1]
        changed = [
            f"{k}: {last.get(k)!r} -> {now[k]!r}" for k in NUMERIC_KEYS if last.get(k) != now[k]
        ]
        if changed:
            note = (
                f"{run_dir} was last trained on another kind of machine ({'; '.join(changed)}): "
                "training goes on, but its checkpoints will not equal those of a run made on one "
                "machine (see panoptic_bench/dsnet/training/platform.py)"
            )
    write_json(Path(run_dir) / PLATFORM_FILE, [*records, now])
    return note
