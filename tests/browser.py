"""A real headless browser for the viewer tests: Debian's chromium driven through its chromedriver
with selenium (both installed by `scripts/setup.sh test`).

:func:`chromium` yields a driver with the flags a closed network needs (no background connections,
no component updates), software WebGL (SwiftShader: CI has no GPU) and the browser's console log
kept; :func:`wait_viewer` waits, in bounded polls, until the page says it is ready or failed, and
:func:`js_errors` returns what the page and the console reported as errors.
"""

from __future__ import annotations

import contextlib
import io
import shutil
import tempfile
import time

import numpy as np

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"


@contextlib.contextmanager
def chromium(width: int = 1400, height: int = 900):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="scanmill-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", f"--window-size={width},{height}", f"--user-data-dir={profile}"):
        opts.add_argument(flag)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def wait_viewer(driver, *, paths: bool = False, polls: int = 600, interval_s: float = 0.1) -> dict:
    """The page's ``window.scanmillViewer`` once it is ready (``paths``: with the tool paths) or failed,
    or asked for a key; at most ``polls`` x ``interval_s`` seconds."""
    state = {}
    for _ in range(polls):
        state = driver.execute_script(
            "const s = window.scanmillViewer; if (!s) return null;"
            "return {ready: s.ready, pathsReady: s.pathsReady, error: s.error || null, errors: s.errors,"
            " firstFrameMs: s.firstFrameMs, bytes: s.bytes, frames: s.frames,"
            " keyform: !document.getElementById('keyform').hidden,"
            " status: document.getElementById('status').textContent}") or {}
        if state.get("error") or state.get("keyform") or (state.get("pathsReady") if paths else state.get("ready")):
            return state
        time.sleep(interval_s)
    return state


def console_entries(driver) -> list[dict]:
    """The SEVERE console entries since the last call (chromedriver hands each entry out once)."""
    return [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]


def js_errors(driver, entries: list[dict] | None = None) -> list[str]:
    """JavaScript errors: what the page caught (window error events, rejected promises) and SEVERE
    console entries from scripts; failed resource loads (source ``network``) are not script errors."""
    page = driver.execute_script("return (window.scanmillViewer && window.scanmillViewer.errors) || []") or []
    entries = console_entries(driver) if entries is None else entries
    return list(page) + [e["message"] for e in entries if e.get("source") != "network"]


def canvas_pixels(driver) -> np.ndarray:
    """(h, w, 3) uint8 RGB of the page's WebGL canvas (read through toDataURL: the drawing buffer is kept)."""
    import base64

    from PIL import Image

    url = driver.execute_script("return document.getElementById('canvas').toDataURL('image/png')")
    data = base64.b64decode(url.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))
