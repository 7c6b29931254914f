"""A real headless Chromium driven over the DevTools protocol, and pixel checks on its screenshots.

Chromium runs with a fresh profile, background networking off and WebGL on SwiftShader (software), so meshcat
renders without a GPU. Screenshots are kept as test artefacts in ``runs/test-artifacts/viz/`` (and in the test's
tmp folder).
"""

from __future__ import annotations

import base64
import colorsys
import io
import json
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARTIFACTS = Path(__file__).resolve().parents[2] / "runs" / "test-artifacts" / "viz"
WINDOW = (1000, 700)


class Chromium:
    """One headless Chromium with one page, driven through the DevTools protocol (websocket)."""

    def __init__(self, profile: Path) -> None:
        from websockets.sync.client import connect

        args = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--disable-default-apps", "--disable-extensions", f"--user-data-dir={profile}",
                "--use-gl=swiftshader", "--enable-unsafe-swiftshader", f"--window-size={WINDOW[0]},{WINDOW[1]}",
                "--remote-debugging-port=0", "about:blank"]
        self.process = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.PIPE, text=True, start_new_session=True)
        self._ws = connect(self._devtools_url(), max_size=None, open_timeout=30).__enter__()
        self._id = 0
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self._session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        self.call("Page.enable")
        self.call("Emulation.setDeviceMetricsOverride", width=WINDOW[0], height=WINDOW[1], deviceScaleFactor=1,
                  mobile=False)

    def _devtools_url(self, timeout_s: float = 30.0) -> str:
        deadline = time.monotonic() + timeout_s
        for line in self.process.stderr:
            match = re.search(r"DevTools listening on (ws://\S+)", line)
            if match:
                return match.group(1)
            if time.monotonic() > deadline:
                break
        raise RuntimeError("chromium did not start its DevTools endpoint")

    def call(self, method: str, **params):
        """One DevTools command (page-level once a page is attached); returns its result."""
        self._id += 1
        message = {"id": self._id, "method": method, "params": params}
        if getattr(self, "_session", None) and not method.startswith("Target."):
            message["sessionId"] = self._session
        self._ws.send(json.dumps(message))
        while True:
            reply = json.loads(self._ws.recv(timeout=60))
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def open(self, url: str) -> None:
        self.call("Page.navigate", url=url)

    def eval(self, expression: str):
        """The value of a JavaScript expression in the page (None if it threw)."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        return None if "exceptionDetails" in result else result["result"].get("value")

    def wait_for(self, expression: str, timeout_s: float = 60.0):
        """Poll a JavaScript expression until it is truthy; returns its value."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            value = self.eval(expression)
            if value:
                return value
            time.sleep(0.2)
        raise AssertionError(f"timed out after {timeout_s} s waiting for: {expression}")

    def screenshot(self, path: Path) -> np.ndarray:
        """Save a PNG of the page and return it as (H, W, 3) uint8 RGB."""
        from PIL import Image

        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(png)
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))

    def close(self) -> None:
        try:
            self._ws.__exit__(None, None, None)
        finally:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(10)


@pytest.fixture(scope="module")
def chromium():
    """A headless Chromium for the module (skipped only where Chromium is not installed)."""
    if CHROMIUM is None:
        pytest.skip("chromium is not installed (CI installs Debian's chromium)")
    profile = Path(tempfile.mkdtemp(prefix="simnav-chromium-"))
    browser = Chromium(profile)
    yield browser
    browser.close()
    shutil.rmtree(profile, ignore_errors=True)


_kept: list[Path] = []


def keep_artifact(path: Path) -> Path:
    """Copy a test artefact to runs/test-artifacts/viz/ and return the copy's path (listed after the run)."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    copy = Path(shutil.copy(path, ARTIFACTS / path.name))
    _kept.append(copy)
    return copy


def pytest_terminal_summary(terminalreporter) -> None:
    for path in _kept:
        terminalreporter.write_line(f"viz artefact: {path}")


def color_pixels(image: np.ndarray, rgb: tuple[float, float, float], hue_tol: float = 0.035,
                 min_saturation: float = 0.45, min_value: float = 0.2) -> int:
    """How many pixels have the hue of ``rgb`` (shading changes brightness, not hue) and are saturated."""
    target_hue = colorsys.rgb_to_hsv(*rgb)[0]
    pixels = image.reshape(-1, 3).astype(np.float64) / 255.0
    vmax, vmin = pixels.max(axis=1), pixels.min(axis=1)
    chroma = vmax - vmin
    saturation = np.where(vmax > 0, chroma / np.maximum(vmax, 1e-9), 0.0)
    r, g, b = pixels.T
    safe = np.maximum(chroma, 1e-9)
    hue = np.select([vmax == r, vmax == g], [((g - b) / safe) % 6, (b - r) / safe + 2], (r - g) / safe + 4) / 6
    distance = np.abs(hue - target_hue)
    distance = np.minimum(distance, 1 - distance)
    return int(np.count_nonzero((distance < hue_tol) & (saturation >= min_saturation) & (vmax >= min_value)))
