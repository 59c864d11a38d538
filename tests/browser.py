"""A headless Chromium for the viewer's tests, driven by selenium; skips with the reason where
the browser, its driver or selenium is missing (`.ci/run` installs Debian's chromium and
chromium-driver when it can).

The flags keep a machine without network quiet: no background connections, component updates
or sync, and a fresh profile per browser. Every wait is for an explicit condition the page sets
(`window.viewerReady`), never a fixed sleep.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

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
WAIT_S = 60  # for a condition the page sets; generous for a loaded machine, never slept


def _missing() -> tuple[str | None, str | None, str | None]:
    """(browser, driver, reason to skip)."""
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
def chromium() -> Iterator:
    """A selenium WebDriver of a fresh headless Chromium; pytest.skip where there is none."""
    browser, driver_path, reason = _missing()
    if reason:
        pytest.skip(reason)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    with tempfile.TemporaryDirectory(prefix="viewer-test-profile-") as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = browser
        for flag in (*FLAGS, f"--user-data-dir={profile}"):
            options.add_argument(flag)
        driver = webdriver.Chrome(options=options, service=Service(driver_path))
        try:
            yield driver
        finally:
            driver.quit()


def open_page(driver, path: Path) -> None:
    """Load a viewer file and wait until it says it is ready (or fails with its message)."""
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(path.resolve().as_uri())
    WebDriverWait(driver, WAIT_S).until(
        lambda d: d.execute_script("return window.viewerReady === true || !!window.viewerError")
    )
    error = driver.execute_script("return window.viewerError || null")
    assert error is None, error


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
