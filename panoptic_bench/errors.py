"""User-facing errors.

Every problem caused by the user's input (a missing file, a wrong point count, an
unknown label id) is raised as :class:`InputError`. The CLI prints its message on one
line and exits with status 2, without a traceback. Messages name the file and say
what to try next.
"""

from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """Bad user input: a file or argument that cannot be used as given.

    Parameters
    ----------
    message : str
        What is wrong and, where it helps, what to try next.
    path : str or Path, optional
        The offending file or directory; prefixed to the message.
    """

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = None if path is None else Path(path)
        self.message = message
        super().__init__(f"{self.path}: {message}" if self.path is not None else message)


class InputErrors(InputError):
    """Several input problems found at once (e.g. by ``validate``), reported together."""

    def __init__(self, problems: list[str], header: str = "input problems found") -> None:
        self.problems = list(problems)
        text = f"{header} ({len(self.problems)}):\n" + "\n".join(f"  - {p}" for p in self.problems)
        super().__init__(text)
