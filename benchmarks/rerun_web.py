"""The Rerun web viewer in a real browser: a recording served by the Rerun CLI, opened by
headless Chromium (software WebGL through SwiftShader) and photographed at 1600 × 1000.

    python -m benchmarks.rerun_web RUN.rrd docs/images/rerun_viewer.png

Needs Debian's ``chromium`` and the dev extra's ``playwright`` (which drives it; no browser is
downloaded).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import time
from pathlib import Path
from urllib.parse import quote

from fusion.rerun_serve import SERVE_HOST, die_with_parent, free_port, rerun_executable

VIEWPORT = {"width": 1600, "height": 1000}
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox"]


def chromium() -> str | None:
    """Debian's Chromium, if installed."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


def screenshot(rrd: Path, out: Path, seconds: float = 60.0) -> Path:
    """Serve ``rrd`` to the web viewer, let the browser load and draw it for ``seconds`` (the
    viewer's WebAssembly and a software rasterizer are slow), and save what it shows."""
    from playwright.sync_api import sync_playwright

    browser_path = chromium()
    if browser_path is None:
        raise RuntimeError("chromium is not installed (Debian package chromium)")
    grpc, web = free_port(), free_port()
    server = subprocess.Popen(
        [rerun_executable(), "--serve-web", "--bind", SERVE_HOST, "--port", str(grpc),
         "--web-viewer-port", str(web), str(rrd)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=die_with_parent)
    try:
        url = (f"http://{SERVE_HOST}:{web}/?url="
               + quote(f"rerun+http://{SERVE_HOST}:{grpc}/proxy", safe=""))
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=browser_path, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport=VIEWPORT)
            deadline = time.monotonic() + 30.0
            while True:  # the server takes a moment to listen
                try:
                    page.goto(url)
                    break
                except Exception:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.5)
            time.sleep(seconds)
            out.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(out))
            browser.close()
    finally:
        server.terminate()
        server.wait(timeout=10)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rrd", type=Path, help="a recording (houghloc run writes run.rrd)")
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("--seconds", type=float, default=100.0,
                        help="time the viewer is given to load and draw")
    args = parser.parse_args(argv)
    print(screenshot(args.rrd, args.out, args.seconds))


if __name__ == "__main__":
    main()
