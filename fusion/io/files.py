"""Atomic file writes: a reader never sees a half-written metrics or config file."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any


@contextmanager
def atomic_file(path: str | Path, mode: str = "w", encoding: str = "utf-8") -> Iterator[IO]:
    """A file to write ``path`` through: a temporary file in the same directory, flushed to disk
    and renamed over ``path`` with ``os.replace`` when the block ends (atomic on POSIX and
    Windows when both names are on one filesystem, which the same directory guarantees). If the
    block raises, even on KeyboardInterrupt, the temporary file is removed and ``path`` is left
    as it was. ``mode``: ``"w"`` (text, no newline translation) or ``"wb"``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    text: dict[str, Any] = {} if "b" in mode else {"encoding": encoding, "newline": ""}
    try:
        with os.fdopen(fd, mode, **text) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp_name, 0o666 & ~_umask())  # mkstemp makes it private; a result is not
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | Path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (:func:`atomic_file`). Returns the path."""
    with atomic_file(path, "w", encoding) as f:
        f.write(text)
    return Path(path)


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_file`). Returns the path."""
    with atomic_file(path, "wb") as f:
        f.write(data)
    return Path(path)


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
