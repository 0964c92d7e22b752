"""The Rerun web viewer served beside a recording: a child process bound to this machine only,
ended with houghloc however houghloc ends.
"""

from __future__ import annotations

import ctypes
import shutil
import signal
import socket
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    pass


PR_SET_PDEATHSIG = 1  # prctl(2): the signal a child gets when its parent ends


SERVE_HOST = "127.0.0.1"  # serve to this machine only: a recording can show where a robot is


GRPC_PORT = 9876


WEB_PORT = 9090


def free_port(host: str = SERVE_HOST) -> int:
    """A TCP port free on ``host`` now (the system's pick), for a server started next."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def web_viewer_command(grpc_uri: str, web_port: int, host: str = SERVE_HOST) -> list[str]:
    """The Rerun CLI serving only the web viewer, on ``host``, pointed at our gRPC server.

    ``rerun.serve_web_viewer`` has no bind address (it listens on 0.0.0.0); the CLI's ``--bind``
    applies to its web server.
    """
    return [rerun_executable(), "--serve-web", "--bind", host,
            "--web-viewer-port", str(web_port), grpc_uri]


def rerun_executable() -> str:
    try:
        import rerun_cli  # the wheel's own binary, matching the SDK's version

        binary = Path(rerun_cli.__file__).parent / "rerun"
        if binary.exists():
            return str(binary)
    except ImportError:
        pass
    return shutil.which("rerun") or "rerun"


def die_with_parent() -> None:
    """In the web viewer's process, before it starts: Linux ends it with SIGTERM when houghloc
    ends, however it ends (close() stops it on a normal exit; a SIGKILL or a crash skips that)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):  # not Linux: close() is what stops it
        pass
