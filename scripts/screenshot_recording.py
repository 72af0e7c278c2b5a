"""A screenshot of a run's recording as rerun's web viewer draws it, taken headless.

    .venv/bin/python scripts/screenshot_recording.py runs/default/run.rrd docs/recording.png

It serves rerun's web viewer with ``rerun --serve-web`` on the loopback address, and the
recording beside it over HTTP; opens the viewer on it in Debian's ``chromium`` (headless,
WebGL through SwiftShader, its software renderer); and drives the page through
Chromium's DevTools protocol: it captures the page every few seconds and keeps the
capture once several in a row agree, at least a minute and a half in, since under the software
renderer the viewer takes 30-60 s to load the recording and draw (Chromium's own
``--screenshot`` flag captures the page before it has drawn). Needs ``chromium``
(``apt-get install chromium``); exit code 2 if it is missing.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
import urllib.request
from contextlib import ExitStack, suppress
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import cv2
import numpy as np
from websockets.sync.client import ClientConnection, connect

WIDTH, HEIGHT = 1600, 1000  # the browser window (px)
SETTLE_S = 5.0  # between captures compared for stillness
STILL = 0.5  # captures whose mean absolute difference (0-255) is below this agree
# this many captures in a row agree: the viewer has loaded and drawn (while it decodes a
# recording it may not redraw for a while, so stillness must last)
STILL_CAPTURES = 8
MIN_WAIT_S = 90.0  # and no sooner: it takes about this long to decode a 20 MB recording


class CrossOrigin(SimpleHTTPRequestHandler):
    """Files for the viewer's page, which is served from another port (CORS allows it)."""

    def end_headers(self) -> None:
        self.send_header("Access-Control-Allow-Origin", "*")
        super().end_headers()

    def log_message(self, format: str, *args: object) -> None:  # quiet
        pass


def started(stack: ExitStack, command: list[str]) -> subprocess.Popen[bytes]:
    """``command`` started in a process group of its own, which ``stack`` ends whole:
    the ``rerun`` entry point runs the viewer's server as a child, and Chromium runs many
    processes, none of which may outlive the screenshot."""
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True)

    def stop() -> None:
        with suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()

    stack.callback(stop)
    return process


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for(url: str, timeout_s: float) -> bytes:
    """The body of ``url`` once it answers (polled)."""
    end = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(url, timeout=5) as answer:
                return bytes(answer.read())
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.5)


def page_socket(port: int) -> str:
    """The DevTools WebSocket address of the page of the Chromium debugged on ``port``."""
    pages = json.loads(wait_for(f"http://127.0.0.1:{port}/json/list", 60))
    return str(next(p for p in pages if p.get("type") == "page")["webSocketDebuggerUrl"])


class DevTools:
    """Calls to one page over its DevTools ``socket`` (a connected WebSocket)."""

    def __init__(self, socket: ClientConnection) -> None:
        self.socket = socket
        self.next_id = 0

    def call(self, method: str, **params: object) -> dict:
        self.next_id += 1
        self.socket.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self.socket.recv(timeout=120))
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return dict(message.get("result", {}))

    def capture(self) -> np.ndarray:
        shot = self.call("Page.captureScreenshot", format="png")
        png = np.frombuffer(base64.b64decode(shot["data"]), np.uint8)
        picture = cv2.imdecode(png, cv2.IMREAD_COLOR)
        if picture is None:
            raise RuntimeError("the page's capture is not a PNG")
        return picture


def screenshot(recording: Path, out: Path, timeout_s: float = 240.0) -> float:
    """Save the viewer's drawing of ``recording`` to ``out`` (PNG); returns the seconds
    it took the viewer to settle."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    rerun = Path(sys.executable).parent / "rerun"
    if browser is None:
        raise FileNotFoundError("chromium not found: apt-get install chromium")
    web, grpc, debug, served = free_port(), free_port(), free_port(), free_port()
    with tempfile.TemporaryDirectory() as profile, ExitStack() as stack:  # processes end first
        started(stack, [str(rerun), "--serve-web", "--bind", "127.0.0.1",
                        "--web-viewer-port", str(web), "--port", str(grpc)])
        # the recording itself over plain HTTP: the viewer reads it whole, at once, rather
        # than as a stream it falls behind on under the software renderer
        files = ThreadingHTTPServer(("127.0.0.1", served), partial(
            CrossOrigin, directory=str(recording.resolve().parent)))
        threading.Thread(target=files.serve_forever, daemon=True).start()
        stack.callback(files.shutdown)
        wait_for(f"http://127.0.0.1:{web}/", 60)
        wait_for(f"http://127.0.0.1:{served}/", 60)
        url = (f"http://127.0.0.1:{web}/?url=http://127.0.0.1:{served}/"
               f"{urllib.parse.quote(recording.name)}")
        started(stack, [browser, "--headless=new", "--no-sandbox", "--use-angle=swiftshader",
                        "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                        "--no-first-run", f"--user-data-dir={profile}",
                        f"--window-size={WIDTH},{HEIGHT}", f"--remote-debugging-port={debug}",
                        "--remote-allow-origins=*", url])
        page = DevTools(stack.enter_context(connect(page_socket(debug), max_size=None,
                                                    open_timeout=30)))
        page.call("Page.enable")
        start = time.monotonic()
        last, agreeing = page.capture(), 0
        while True:
            time.sleep(SETTLE_S)
            now = page.capture()
            still = float(np.abs(now.astype(int) - last.astype(int)).mean()) < STILL
            agreeing = agreeing + 1 if still else 0
            if agreeing >= STILL_CAPTURES and time.monotonic() - start > MIN_WAIT_S:
                break
            if time.monotonic() - start > timeout_s:
                raise TimeoutError(f"the viewer did not settle in {timeout_s:.0f} s")
            last = now
        out.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out), now)
        return time.monotonic() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path, help="a run's run.rrd")
    parser.add_argument("out", type=Path, help="the screenshot to write (PNG)")
    parser.add_argument("--timeout", type=float, default=240.0, help="seconds to wait at most")
    args = parser.parse_args()
    if not args.recording.is_file():
        print(f"screenshot: {args.recording}: no such recording", file=sys.stderr)
        return 2
    try:
        took = screenshot(args.recording, args.out, args.timeout)
    except FileNotFoundError as exc:
        print(f"screenshot: {exc}", file=sys.stderr)
        return 2
    print(f"screenshot: {args.out} after {took:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
