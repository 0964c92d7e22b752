"""Atomic file writes: a reader never sees a half-written metrics or config file."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any


def atomic_write_text(path: str | Path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically: a temporary file in the same directory, then
    ``os.replace`` (atomic on POSIX and Windows when both names are on one filesystem, which the
    same directory guarantees). Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding=encoding, newline="") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp_name, 0o666 & ~_umask())  # mkstemp makes it private; a result is not
        os.replace(tmp_name, path)
    except BaseException:
        # Leave no stray temporary file behind, whatever went wrong (even KeyboardInterrupt).
        Path(tmp_name).unlink(missing_ok=True)
        raise
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_json(path: str | Path, obj: Any, indent: int = 2) -> Path:
    """Serialise ``obj`` to JSON and write it atomically. NumPy scalars and arrays are converted;
    NaN/inf are refused (they are not JSON), so a metrics file is always valid JSON."""
    text = json.dumps(obj, indent=indent, default=_to_json, allow_nan=False, sort_keys=False)
    return atomic_write_text(path, text + "\n")


def _to_json(value: Any) -> Any:
    # NumPy types appear in metrics dictionaries all the time; json cannot serialise them itself.
    tolist = getattr(value, "tolist", None)
    if callable(tolist):
        return tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"object of type {type(value).__name__} is not JSON serialisable")
