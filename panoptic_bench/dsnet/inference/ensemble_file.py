"""Ensemble files: a fixed set of checkpoints and test-time views, used where a checkpoint is.

An ensemble file is a small JSON document::

    {"format": "panoptic-bench-ensemble/1",
     "members": ["dsnet_a.pt", "dsnet_b.pt", "dsnet_c.pt"],
     "tta_views": 4,
     "notes": "free text (optional)"}

Member paths are relative to the file's folder (or absolute). ``infer --checkpoint E.json``
(and ``demo --checkpoint``) predicts exactly as ``infer --checkpoint A --ensemble B C
--tta-views 4`` does (:mod:`panoptic_bench.dsnet.inference.ensemble`): the first member gives
dynamic shifting, the density policy and the inference settings; ``--tta-views`` on the command
line overrides the file's views and ``--ensemble`` adds members. ``checkpoint ensemble`` writes
one. A shipped name may point at an ensemble file (``synthetic-ensemble``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from panoptic_bench.errors import InputError

FORMAT = "panoptic-bench-ensemble/1"
_KEYS = ("format", "members", "tta_views", "notes")

__all__ = [
    "FORMAT",
    "EnsembleFile",
    "is_ensemble_file",
    "read_ensemble_file",
    "write_ensemble_file",
]


@dataclass(frozen=True)
class EnsembleFile:
    """A parsed ensemble file.

    Attributes
    ----------
    path : Path
        The file itself.
    members : tuple of Path
        Checkpoint files (resolved against the file's folder), the first one leading.
    tta_views : int
        Test-time views per member (1-16).
    notes : str
        What the members are (free text).
    """

    path: Path
    members: tuple[Path, ...]
    tta_views: int
    notes: str = ""


def is_ensemble_file(path: str | Path) -> bool:
    """True for a ``.json`` path: checkpoints are ``.pt`` files, ensemble files JSON."""
    return Path(path).suffix.lower() == ".json"


def read_ensemble_file(path: str | Path) -> EnsembleFile:
    """Read and check an ensemble file (the members must exist; they are not loaded here).

    Raises
    ------
    InputError
        Missing or unreadable file, wrong format, unknown keys, no members, views outside 1-16,
        or a member that is not a file; the message names the ensemble file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("ensemble file not found; write one with `checkpoint ensemble`", path)
    try:
        raw = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read ensemble file ({type(exc).__name__}: {exc})", path) from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise InputError(f"not a panoptic-bench ensemble file (format {FORMAT})", path)
    unknown = sorted(set(raw) - set(_KEYS))
    if unknown:
        raise InputError(f"unknown keys {unknown} (known: {', '.join(_KEYS)})", path)
    members = raw.get("members")
    if not isinstance(members, list) or not members or not all(isinstance(m, str) for m in members):
        raise InputError("'members' must be a non-empty list of checkpoint paths", path)
    views = raw.get("tta_views", 1)
    if isinstance(views, bool) or not isinstance(views, int) or not 1 <= views <= 16:
        raise InputError(f"'tta_views' must be an integer in 1..16, got {views!r}", path)
    notes = raw.get("notes", "")
    if not isinstance(notes, str):
        raise InputError("'notes' must be a string", path)
    resolved = tuple(Path(os.path.normpath(path.parent.absolute() / m)) for m in members)
    for given, member in zip(members, resolved, strict=True):
        if is_ensemble_file(member):
            raise InputError(f"member {given!r} is itself an ensemble file; list checkpoints", path)
        if not member.is_file():
            raise InputError(f"member checkpoint {given!r} not found ({member})", path)
    return EnsembleFile(path, resolved, views, notes)


def expand_ensemble_file(
    checkpoint: str | Path, ensemble: Sequence[str | Path], tta_views: int | None
) -> tuple[str | Path, tuple[str | Path, ...], int | None, EnsembleFile | None]:
    """``(checkpoint, ensemble, tta_views, file)`` with an ensemble file replaced by its contents.

    For a ``.pt`` checkpoint the arguments come back unchanged (``file`` None); for an ensemble
    file, its first member, the other members followed by ``ensemble``, and ``tta_views`` if given
    (else the file's views).
    """
    if not is_ensemble_file(checkpoint):
        return checkpoint, tuple(ensemble), tta_views, None
    spec = read_ensemble_file(checkpoint)
    views = spec.tta_views if tta_views is None else tta_views
    return spec.members[0], (*spec.members[1:], *ensemble), views, spec


def write_ensemble_file(
    path: str | Path, members: Sequence[str | Path], tta_views: int = 1, notes: str = ""
) -> EnsembleFile:
    """Atomically write an ensemble file and return it as read back.

    Members are stored relative to the file's folder (so a folder of checkpoints and its
    ensemble file move together); a member on another drive stays absolute.
    """
    from panoptic_bench.io import write_json

    path = Path(path)
    if not is_ensemble_file(path):
        raise InputError("an ensemble file is a .json file", path)
    if not members or not 1 <= int(tta_views) <= 16:
        raise InputError("an ensemble needs at least one member and 1..16 views", path)
    stored = []
    for m in members:
        if is_ensemble_file(m) or not Path(m).is_file():
            raise InputError("not a checkpoint file (members are .pt checkpoints)", m)
        absolute = Path(m).resolve()
        try:
            stored.append(os.path.relpath(absolute, path.parent.resolve()))
        except ValueError:  # another drive (Windows)
            stored.append(str(absolute))
    doc = {"format": FORMAT, "members": stored, "tta_views": int(tta_views)}
    if notes:
        doc["notes"] = notes
    write_json(path, doc)
    return read_ensemble_file(path)
