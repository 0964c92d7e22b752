"""Open a text log that may be gzip-compressed, refusing binary files with a clear error; read
a table of numbers with every malformed line named."""

from __future__ import annotations

import gzip
import io
import math
from array import array
from pathlib import Path
from typing import TextIO

import numpy as np
from numpy.typing import NDArray

from fusion.io.errors import LogError

GZIP_MAGIC = b"\x1f\x8b"
_SNIFF_BYTES = 65536


def is_gzip(path: Path) -> bool:
    """True when the file starts with the gzip magic bytes (the extension is not trusted)."""
    with path.open("rb") as f:
        return f.read(2) == GZIP_MAGIC


def open_text_log(path: str | Path) -> TextIO:
    """Open a plain or gzip text file for line-by-line reading.

    Raises ``LogError`` for a missing path, a directory, a broken gzip header, or binary content
    (a NUL byte in the first 64 KiB). Undecodable bytes later in the file become U+FFFD, so a
    corrupted line turns into a bad record with a line number instead of a decode traceback.
    """
    path = Path(path)
    if not path.exists():
        raise LogError(path, "file not found")
    if path.is_dir():
        raise LogError(path, "is a directory, expected a text log")
    try:
        compressed = is_gzip(path)
        raw = gzip.open(path, "rb") if compressed else path.open("rb")
        head = raw.peek(_SNIFF_BYTES)[:_SNIFF_BYTES] if hasattr(raw, "peek") else b""
    except (OSError, EOFError) as err:  # gzip.BadGzipFile is an OSError
        raise LogError(path, f"cannot read ({'gzip' if compressed else 'file'}: {err})") from None
    if b"\x00" in head:
        raw.close()
        raise LogError(path, "binary data (NUL bytes), not a text log")
    return io.TextIOWrapper(raw, encoding="utf-8", errors="replace", newline=None)


def read_numeric_table(path: str | Path, columns: int, limit: int | None = None
                       ) -> NDArray[np.float64]:
    """Rows of ``columns`` finite numbers, as an N×columns array (N ≥ 0).

    Blank lines and ``#`` comments are skipped; a line with another number of fields, a
    non-numeric or a non-finite value raises ``LogError`` naming its line (a reference must not
    be silently incomplete). ``limit``: stop after that many rows. Values are collected in a flat
    array of doubles (8 bytes each, not a Python float object per value): an hour of poses costs
    a few MB, not tens.
    """
    path = Path(path)
    if not path.is_file():
        raise LogError(path, "file not found")
    flat = array("d")
    with path.open(encoding="utf-8", errors="replace") as f:
        for number, line in enumerate(f, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            fields = text.split()
            if len(fields) != columns:
                raise LogError(path, f"line {number}: expected {columns} fields, "
                                     f"found {len(fields)}")
            try:
                values = [float(v) for v in fields]
            except ValueError:
                raise LogError(path, f"line {number}: non-numeric field in {text[:60]!r}") from None
            if not all(math.isfinite(v) for v in values):
                raise LogError(path, f"line {number}: non-finite value")
            flat.extend(values)
            if limit is not None and len(flat) >= columns * limit:
                break
    return np.frombuffer(flat, dtype=np.float64).reshape(-1, columns)
