"""World profiles by name or from YAML files (:func:`load_profile`).

A profile file is a mapping of :class:`~panoptic_bench.datasets.synthetic.profile.WorldProfile`
fields that overrides its ``base``: a profile name (``classic``, the default, or ``realistic``) or
another profile file, given relative to the file that names it. A realism row that changes one key
of an existing world is then two lines, ``base: that_world.yaml`` and the key::

    # configs/synth_example.yaml
    base: synth_realistic_low_crowns_low_fences.yaml
    fence_lattice: 0.5
"""

from __future__ import annotations

from pathlib import Path

from panoptic_bench.datasets.synthetic.profile import CLASSIC, PROFILES, WorldProfile
from panoptic_bench.errors import InputError

__all__ = ["load_profile"]

MAX_DEPTH = 8  # profile files chained through ``base``


def load_profile(spec: str | WorldProfile | None) -> WorldProfile:
    """A profile by name (``classic``, ``realistic``), from a YAML file, or as given.

    Raises :class:`InputError` naming the file for an unreadable or invalid file, an unknown
    base, a chain of ``base`` files that loops or is deeper than ``MAX_DEPTH``, or a bad key.
    """
    if spec is None:
        return CLASSIC
    if isinstance(spec, WorldProfile):
        return spec
    if spec in PROFILES:
        return PROFILES[spec]
    path = Path(spec)
    if path.suffix not in (".yaml", ".yml"):
        raise InputError(f"unknown profile {spec!r}; use classic, realistic or a .yaml file")
    return _load_file(path, ())


def _load_file(path: Path, chain: tuple[Path, ...]) -> WorldProfile:
    import yaml

    key = path.resolve()
    if key in chain:
        raise InputError("profile files name each other as base in a loop", path)
    if len(chain) >= MAX_DEPTH:
        raise InputError(f"more than {MAX_DEPTH} profile files chained through base", path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise InputError(f"cannot read profile ({exc.strerror})", path) from None
    except yaml.YAMLError as exc:
        raise InputError(f"profile is not valid YAML ({exc})", path) from None
    if not isinstance(data, dict):
        raise InputError("a profile file must be a mapping", path)
    data = dict(data)
    base = data.pop("base", "classic")
    if isinstance(base, str) and base in PROFILES:
        parent = PROFILES[base]
    elif isinstance(base, str) and base.endswith((".yaml", ".yml")):
        parent = _load_file(path.parent / base, (*chain, key))
    else:
        raise InputError(
            f"unknown base profile {base!r}; use classic, realistic or a .yaml file", path
        )
    return WorldProfile.from_dict(data, path, base=parent)
