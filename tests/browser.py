"""A headless Chromium for the viewer's tests, driven by selenium; skips with the reason where
the browser, its driver or selenium is missing (`.ci/run` installs Debian's chromium and
chromium-driver when it can). The viewer's benchmark and the docs' screenshot use the same
launcher (`find_chromium`, `launch`).

The flags keep a machine without network quiet: no background connections, component updates
or sync, and a fresh profile per browser. Every wait is for an explicit condition the page sets
(`window.viewerReady`) or an effect of the input (`until`), never a fixed sleep.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--force-device-scale-factor=1",  # CSS pixels are canvas pixels: the tests' arithmetic
    "--window-size=1400,1000",
)
BROWSERS = ("chromium", "chromium-browser", "google-chrome")
BROWSER_PAGES = ("chrome://", "chrome-untrusted://")  # the browser's own user interface
WAIT_S = 60  # for a condition the page sets; generous for a loaded machine, never slept


def find_chromium() -> tuple[str | None, str | None, str | None]:
    """(browser, driver, None) where both are on PATH and selenium imports, else
    (None, None, the reason in one line)."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return None, None, "selenium is not installed (pip install -e '.[dev]')"
    browser = next((path for name in BROWSERS if (path := shutil.which(name))), None)
    driver = shutil.which("chromedriver")
    if browser is None or driver is None:
        what = " and ".join(
            name for name, path in (("chromium", browser), ("chromedriver", driver)) if not path
        )
        return None, None, f"no {what} on PATH (apt-get install chromium chromium-driver)"
    return browser, driver, None


@contextmanager
def launch(browser: str, driver_path: str, window: tuple[int, int] = (1400, 1000)) -> Iterator:
    """A selenium WebDriver of a fresh headless Chromium with its own temporary profile; its
    DevTools performance log records every request the pages make (`requested`)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    with tempfile.TemporaryDirectory(prefix="viewer-browser-profile-") as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = browser
        size, own = f"--window-size={window[0]},{window[1]}", f"--user-data-dir={profile}"
        for flag in (*(f for f in FLAGS if not f.startswith("--window-size=")), size, own):
            options.add_argument(flag)
        options.set_capability("goog:loggingPrefs", {"performance": "ALL"})
        driver = webdriver.Chrome(options=options, service=Service(driver_path))
        try:
            yield driver
        finally:
            driver.quit()


@contextmanager
def chromium() -> Iterator:
    """A selenium WebDriver of a fresh headless Chromium; pytest.skip where there is none."""
    import pytest

    browser, driver_path, reason = find_chromium()
    if reason:
        pytest.skip(reason)
    with launch(browser, driver_path) as driver:
        yield driver


def open_page(driver, path: Path) -> None:
    """Load a viewer file and wait until it says it is ready (or fails with its message)."""
    driver.get(path.resolve().as_uri())
    until(driver, "return window.viewerReady === true || !!window.viewerError")
    error = driver.execute_script("return window.viewerError || null")
    assert error is None, error


def requested(driver) -> list[str]:
    """The URLs the browser requested since the last call (or its start), in order: the page's
    own file and anything it loads (scripts, styles, fonts, images, fetches, frames), failed
    ones too; not those of the browser's own pages (chrome://, e.g. a fresh browser's new tab,
    and what they load)."""
    events = (json.loads(entry["message"])["message"] for entry in driver.get_log("performance"))
    sent = (e["params"] for e in events if e["method"] == "Network.requestWillBeSent")
    urls = ((r["request"]["url"], r.get("documentURL", "")) for r in sent)
    return [
        u for u, page in urls if not (u.startswith(BROWSER_PAGES) or page.startswith(BROWSER_PAGES))
    ]


def until(driver, script: str, *args) -> None:
    """Wait until the page's `script` (a JavaScript function body, `return ...`) is true:
    input events reach the page asynchronously, so a test waits for their effect."""
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(driver, WAIT_S).until(lambda d: d.execute_script(script, *args))


def pixel(driver, canvas_id: str, col: float, row: float) -> tuple[int, int, int]:
    """RGB of the canvas pixel that holds the point (col, row) [CSS px = canvas px]."""
    return tuple(
        driver.execute_script(
            "const c = document.getElementById(arguments[0]);"
            "return Array.from(c.getContext('2d').getImageData(arguments[1], arguments[2], 1, 1)"
            ".data.slice(0, 3));",
            canvas_id,
            int(col),
            int(row),
        )
    )
