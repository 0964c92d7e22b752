"""The one exception readers and writers raise for a file they cannot use."""

from __future__ import annotations

from pathlib import Path


class LogError(Exception):
    """A log or trajectory file that cannot be used at all (missing, wrong format, no records).

    Bad *records* inside a usable file are not errors: readers skip them with a warning.
    """

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")
