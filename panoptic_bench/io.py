"""Small file helpers shared by every writer: atomic writes and output-directory checks.

Outputs are written to a temporary file in the destination directory and renamed into
place, so an interrupted run never leaves a half-written file behind. Files get the mode of an
ordinary write (``0o666`` minus the umask), not ``mkstemp``'s private ``0o600``. A full disk
(``ENOSPC``) is a user error: :class:`~panoptic_bench.errors.InputError`, temp file removed.

Trees of files (predictions, centres, label sets) are written with :func:`output_tree`: into a
temporary sibling directory that is renamed into place only when every file is complete, so an
error or Ctrl-C on the last scan leaves nothing behind. :func:`check_output_dir` and
:func:`check_output_file` are the output policy shared by every command: never inside (or equal
to) an input, never over a non-empty directory or an existing file without ``overwrite``.
:func:`read_npz` reads an input archive, turning any corruption into an ``InputError``.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
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
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise _write_error(exc, path) from None
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        full = full_disk_error(exc)
        if full is not None:
            raise _write_error(full, path) from None
        raise


#: errno values of a full disk or exhausted quota: user errors, reported as InputError.
FULL_DISK = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def full_disk_error(exc: BaseException | None) -> OSError | None:
    """The ENOSPC/EDQUOT/EFBIG ``OSError`` in ``exc`` or its context chain, if any.

    A writer that fails on a full disk often raises something else while cleaning up (zipfile:
    ``ValueError: seek of closed file``); the disk error is then only in ``__context__``.
    """
    seen = 0
    while exc is not None and seen < 16:
        if isinstance(exc, OSError) and exc.errno in FULL_DISK:
            return exc
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


def current_umask() -> int:
    """The process umask (read without changing it for longer than one call)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _write_error(exc: OSError, path: Path) -> Exception:
    """InputError for a write that failed for a user-fixable reason; other errors unchanged."""
    if exc.errno in FULL_DISK:
        return InputError("no space left on the device; free space or choose another output", path)
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return InputError(f"cannot write here ({exc.strerror}); choose another output", path)
    return exc


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
    """Atomically write a ``.npz`` archive (the name is kept exactly, no suffix added).

    The archive is built in memory, then written in one call: a full disk then fails in a plain
    ``write`` (no half-closed ``ZipFile`` left to complain at garbage collection).
    """
    import io

    buffer = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buffer, **arrays)
    write_bytes(path, buffer.getvalue())


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
                f"output lies inside the input tree {src}; choose another output directory",
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


def check_output_dir(output: str | Path, *, overwrite: bool, inputs: tuple | list = ()) -> None:
    """The shared policy for an output directory; creates nothing.

    Raises :class:`InputError` if ``output`` equals or lies inside one of ``inputs``, is a file,
    or is a non-empty directory while ``overwrite`` is False. Call it before reading the inputs.
    """
    check_output_location(output, inputs)
    out = Path(output)
    if not overwrite and out.is_dir() and any(out.iterdir()):
        raise InputError(
            "output directory exists and is not empty; pass --overwrite to replace its files "
            "or choose another output",
            output,
        )


def check_output_file(output: str | Path, *, overwrite: bool, inputs: tuple | list = ()) -> None:
    """The shared policy for a single output file; creates nothing.

    Raises :class:`InputError` if ``output`` is one of the ``inputs`` (same path or same file),
    lies inside an input directory, is a directory, or exists while ``overwrite`` is False.
    """
    out = Path(output).resolve()
    for src in inputs:
        src_path = Path(src).resolve()
        same = out == src_path or (
            out.exists() and src_path.exists() and os.path.samefile(out, src_path)
        )
        if same:
            raise InputError("output is the input file; choose another output path", output)
        if src_path.is_dir() and src_path in out.parents:
            raise InputError(f"output lies inside the input tree {src_path}", output)
    if out.is_dir():
        raise InputError("output is a directory; give a file path", output)
    if out.exists() and not overwrite:
        raise InputError("output file exists; pass --overwrite to replace it", output)


@contextlib.contextmanager
def output_tree(
    output: str | Path, *, overwrite: bool = False, inputs: tuple | list = ()
) -> Iterator[Path]:
    """Write a directory tree all-or-nothing: yield a temporary sibling, rename it into place.

    Parameters
    ----------
    output : str or Path
        Final directory; checked with :func:`check_output_dir` first.
    overwrite : bool
        Allow a non-empty ``output``: the new files then replace files of the same name in it
        (each by an atomic rename), other files stay.
    inputs : tuple of paths
        Input trees ``output`` may not lie in.

    Yields
    ------
    Path
        An empty directory (same file system as ``output``) to write everything into. On any
        error or interruption it is deleted and ``output`` is left exactly as it was.
    """
    check_output_dir(output, overwrite=overwrite, inputs=inputs)
    final = Path(output).resolve()
    home = final.parent  # the temp tree lives in the nearest existing ancestor: on failure no
    while not home.exists():  # directory at all has been created, not even a parent
        home = home.parent
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".partial", dir=home))
        os.chmod(tmp, 0o777 & ~current_umask())
    except OSError as exc:
        raise _write_error(exc, final) from None
    try:
        yield tmp
        _publish_tree(tmp, final)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, InputError) and str(tmp) in str(exc):  # name the real output path
            raise InputError(str(exc).replace(str(tmp), str(final))) from None
        full = full_disk_error(exc)
        if full is not None or isinstance(exc, OSError):
            raise _write_error(full or exc, final) from None
        raise


def _publish_tree(tmp: Path, final: Path) -> None:
    """Move the finished tree ``tmp`` to ``final`` (rename, or file by file into a non-empty one)."""
    if final.is_dir() and not any(final.iterdir()):
        final.rmdir()
    final.parent.mkdir(parents=True, exist_ok=True)
    if not final.exists():
        os.rename(tmp, final)
        return
    for src in sorted(p for p in tmp.rglob("*") if not p.is_dir()):
        dest = final / src.relative_to(tmp)
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(src, dest)
    shutil.rmtree(tmp)


def read_npz(path: str | Path, keys: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Read every array of a ``.npz`` archive, turning any corruption into :class:`InputError`.

    A raw ``.npy`` file, a truncated archive, a CRC or zlib error, pickled objects and missing
    ``keys`` all raise :class:`InputError` naming ``path`` (never a ``BadZipFile`` traceback).

    Returns
    -------
    dict of str to ndarray
        Every member, fully decompressed (so a corrupt member fails here, not later).
    """
    import zipfile
    import zlib

    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    try:
        npz = np.load(path, allow_pickle=False)
        if not isinstance(npz, np.lib.npyio.NpzFile):
            raise InputError("not an .npz archive (a raw .npy array?); save with np.savez", path)
        with npz:
            arrays = {name: npz[name] for name in npz.files}
    except InputError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        raise InputError(
            f"cannot read npz, the file is corrupt or truncated ({exc})", path
        ) from None
    missing = [k for k in keys if k not in arrays]
    if missing:
        raise InputError(
            f"npz has no {', '.join(map(repr, missing))} array (found: {sorted(arrays)})", path
        )
    return arrays
