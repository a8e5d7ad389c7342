"""A headless Chromium driven over the DevTools protocol: open a page, wait until it shows what is
expected, take a screenshot. Used to check and to picture the web viewer (tests, tools/screenshots.py).

WebGL runs in software (SwiftShader: ``--use-angle=swiftshader --enable-unsafe-swiftshader``), so
no GPU or display is needed. The binary is ``$SCENELABEL_CHROMIUM`` or the first of
:data:`CHROMIUM_NAMES` on the PATH (Debian: ``apt-get install chromium``; tools/setup.sh installs it
where it can).
"""

from __future__ import annotations

import base64
import io
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["CHROMIUM_NAMES", "CHROMIUM_FLAGS", "find_chromium", "HeadlessBrowser", "screenshot", "colour_fraction"]

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")
CHROMIUM_FLAGS = (
    "--headless=new",
    "--use-angle=swiftshader",  # WebGL in software: no GPU, no display
    "--enable-unsafe-swiftshader",
    "--hide-scrollbars",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-extensions",
    "--mute-audio",
)
_LISTENING = re.compile(r"DevTools listening on (ws://\S+)")


def find_chromium() -> str | None:
    """The Chromium (or Chrome) binary to use: ``$SCENELABEL_CHROMIUM``, else the first of
    :data:`CHROMIUM_NAMES` on the PATH; None when there is none."""
    own = os.environ.get("SCENELABEL_CHROMIUM")
    if own:
        return own if shutil.which(own) else None
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


class HeadlessBrowser:
    """One headless Chromium page, as a context manager.

    Args:
        width, height: the page's viewport in CSS pixels (device scale 1).
        binary: the browser (default: :func:`find_chromium`).
        timeout: seconds to wait for the browser to start and to answer a command.
    Raises:
        FileNotFoundError: no browser found.
        TimeoutError: it did not start in time.
    """

    def __init__(self, width: int = 800, height: int = 600, binary: str | None = None, timeout: float = 60.0):
        binary = binary or find_chromium()
        if binary is None:
            raise FileNotFoundError("no chromium found (install Debian's `chromium` or set SCENELABEL_CHROMIUM)")
        self.width, self.height, self.timeout = int(width), int(height), float(timeout)
        self._dir = tempfile.mkdtemp(prefix="scenelabel-chromium-")
        self._log = open(Path(self._dir) / "stderr.log", "w+b")  # drained by the OS, never a full pipe
        args = [binary, *CHROMIUM_FLAGS, f"--window-size={self.width},{self.height}", "--remote-debugging-port=0",
                f"--user-data-dir={Path(self._dir) / 'profile'}", "about:blank"]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            args.insert(1, "--no-sandbox")  # Chromium refuses to run as root with its sandbox
        self._proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=self._log)
        self._ws = None
        self._next_id = 0
        self.captured_at = float("nan")  # time.perf_counter() when the last screenshot arrived
        try:
            self._connect()
        except BaseException:
            self.close()
            raise

    def _connect(self) -> None:
        from websockets.sync.client import connect

        deadline = time.monotonic() + self.timeout
        browser_url = None
        while browser_url is None:
            if self._proc.poll() is not None or time.monotonic() > deadline:
                self._log.seek(0)
                tail = self._log.read().decode(errors="replace")[-2000:]
                raise TimeoutError(f"chromium did not start (exit {self._proc.poll()}):\n{tail}")
            time.sleep(0.05)
            self._log.seek(0)
            found = _LISTENING.search(self._log.read().decode(errors="replace"))
            browser_url = found.group(1) if found else None
        port = browser_url.split("/")[2].split(":")[1]
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=self.timeout) as reply:
            pages = [t for t in json.loads(reply.read()) if t.get("type") == "page"]
        self._ws = connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=self.timeout)
        metrics = {"width": self.width, "height": self.height, "deviceScaleFactor": 1, "mobile": False}
        self.send("Emulation.setDeviceMetricsOverride", **metrics)

    def send(self, method: str, **params) -> dict:
        """One DevTools command; returns its result (events that arrive meanwhile are dropped).

        Raises:
            RuntimeError: the browser answered with an error.
        """
        self._next_id += 1
        self._ws.send(json.dumps({"id": self._next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self._ws.recv(timeout=self.timeout))
            if message.get("id") == self._next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})

    def open(self, url: str) -> None:
        """Load ``url`` in the page."""
        self.send("Page.enable")
        self.send("Page.navigate", url=url)

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (JSON-able values)."""
        result = self.send("Runtime.evaluate", expression=expression, returnByValue=True)
        return result.get("result", {}).get("value")

    def screenshot(self) -> np.ndarray:
        """The page as an [height, width, 3] uint8 RGB image (a PNG encoded for speed, not size:
        lossless all the same). ``captured_at`` is then the ``time.perf_counter()`` at which it arrived."""
        from PIL import Image

        data = base64.b64decode(self.send("Page.captureScreenshot", format="png", optimizeForSpeed=True)["data"])
        self.captured_at = time.perf_counter()
        with Image.open(io.BytesIO(data)) as im:
            return np.asarray(im.convert("RGB"))

    def wait_for(
        self, ready: Callable[[np.ndarray], bool], timeout: float = 60.0, interval: float = 0.05
    ) -> np.ndarray:
        """Screenshots until ``ready(image)`` holds; returns that image. ``captured_at`` is then when
        it arrived: the page showed it by then (the check's own time, and the wait between
        screenshots, are the poller's, not the page's).

        Raises:
            TimeoutError: not within ``timeout`` seconds (the message says so; the last image is
                the error's ``image`` attribute).
        """
        deadline = time.monotonic() + timeout
        image = None
        while True:
            try:
                image = self.screenshot()
            except RuntimeError as error:  # a page still being swapped in after open(): not ready yet
                if "Not attached to an active page" not in str(error) or time.monotonic() > deadline:
                    raise
                image = None
            if image is not None and ready(image):
                return image
            if time.monotonic() > deadline:
                err = TimeoutError(f"the page did not show what was expected within {timeout:g} s")
                err.image = image  # type: ignore[attr-defined]
                raise err
            time.sleep(interval)

    def close(self) -> None:
        """Close the page and end the browser (idempotent)."""
        if self._ws is not None:
            try:
                self._ws.close()
            except Exception:  # the browser may be gone already
                pass
            self._ws = None
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._log.close()
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> "HeadlessBrowser":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def screenshot(
    url: str,
    out: str | Path | None = None,
    size: tuple[int, int] = (800, 600),
    ready: Callable[[np.ndarray], bool] | None = None,
    timeout: float = 60.0,
) -> np.ndarray:
    """Open ``url`` in a headless Chromium and take a screenshot once ``ready(image)`` holds (by
    default: once the page is not blank).

    Args:
        url: the page.
        out: also write the screenshot there as PNG.
        size: (width, height) of the viewport.
        ready: when the page is ready to be pictured.
        timeout: seconds to wait for the browser and for ``ready``.
    Returns:
        [height, width, 3] uint8 RGB.
    """
    ready = ready or (lambda image: image.std() > 1.0)
    with HeadlessBrowser(size[0], size[1], timeout=timeout) as browser:
        browser.open(url)
        image = browser.wait_for(ready, timeout)
    if out is not None:
        from PIL import Image

        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(image).save(out)
    return image


def colour_fraction(image: np.ndarray, color, tolerance: int = 40) -> float:
    """Fraction of the pixels of ``image`` [h, w, 3] within ``tolerance`` (the sum of the channels'
    differences) of ``color`` (r, g, b): how much of a screenshot shows a class's colour."""
    return float((np.abs(image.astype(int) - np.asarray(color)).sum(-1) <= tolerance).mean())
