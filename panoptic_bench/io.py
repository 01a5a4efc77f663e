"""Small file helpers shared by every writer: atomic writes and output-directory checks.

Outputs are written to a temporary file in the destination directory and renamed into
place, so an interrupted run never leaves a half-written file behind.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from panoptic_bench.errors import InputError


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "w", **kwargs: Any) -> Iterator[IO]:
    """Open ``path`` for writing through a temporary sibling file renamed on success.

    Parameters
    ----------
    path : str or Path
        Final destination. Parent directories are created.
    mode : str
        ``"w"`` (text) or ``"wb"`` (binary).
    """
    if "r" in mode or "a" in mode:
        raise ValueError("atomic_open only writes")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_bytes(path: str | Path, data: bytes) -> None:
    """Atomically write ``data`` to ``path``."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)


def write_text(path: str | Path, text: str) -> None:
    """Atomically write ``text`` (UTF-8) to ``path``."""
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write(text)


def write_json(path: str | Path, obj: Any, indent: int | None = 2) -> None:
    """Atomically write ``obj`` as JSON."""
    write_text(path, json.dumps(obj, indent=indent, sort_keys=False) + "\n")


def write_array(path: str | Path, array: np.ndarray) -> None:
    """Atomically write the raw bytes of ``array`` (C order), as ``.bin``/``.label`` files are."""
    write_bytes(path, np.ascontiguousarray(array).tobytes())


def write_npz(path: str | Path, compressed: bool = True, **arrays: np.ndarray) -> None:
    """Atomically write a ``.npz`` archive (the name is kept exactly, no suffix added)."""
    with atomic_open(path, "wb") as fh:
        (np.savez_compressed if compressed else np.savez)(fh, **arrays)


def check_output_location(output: str | Path, inputs: tuple | list = ()) -> None:
    """Raise :class:`InputError` if ``output`` is, or lies inside, one of ``inputs``.

    Creates nothing: call it before a long computation, then :func:`ensure_output_dir` when
    the results are ready.
    """
    out = Path(output).resolve()
    for src in inputs:
        src = Path(src).resolve()
        if out == src or src in out.parents:
            raise InputError(
                f"output directory lies inside the input tree {src}; choose another --output",
                output,
            )
    if out.exists() and not out.is_dir():
        raise InputError("output exists and is not a directory", output)


def ensure_output_dir(path: str | Path, *, overwrite: bool = True, inputs: tuple = ()) -> Path:
    """Create the output directory ``path`` and refuse unsafe destinations.

    Parameters
    ----------
    path : str or Path
        Output directory.
    overwrite : bool
        If False, a non-empty existing directory is an error (pass ``--overwrite``).
    inputs : tuple of paths
        Input trees that must never be written into: ``path`` may not lie inside any.
    """
    check_output_location(path, inputs)
    out = Path(path).resolve()
    if out.exists() and not overwrite and any(out.iterdir()):
        raise InputError("output directory is not empty; pass --overwrite to replace it", path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output directory ({exc.strerror})", path) from None
    return out
