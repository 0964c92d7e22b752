"""Open a text log that may be gzip-compressed, refusing binary files with a clear error."""

from __future__ import annotations

import gzip
import io
from pathlib import Path
from typing import TextIO

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
