"""Debian's headless Chromium for the browser tests (tests/test_viewer.py, tests/test_export_browser.py,
tests/test_export.py's npm packages): where it is, whether a missing one skips or fails, and a driver.

Without /usr/bin/chromium (or npm) a browser test skips, except on CI (``CI`` or ``FRNG_REQUIRE_BROWSER`` set, as
.ci/run does after installing it), where it fails."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")
HEADLESS = (
    "--headless --no-sandbox --disable-gpu --no-first-run --disable-background-networking --disable-component-update "
    "--disable-sync --force-device-scale-factor=1"
).split()


def required() -> bool:
    """True on CI: a missing browser (or npm) fails the test instead of skipping it."""
    return bool(os.environ.get("CI") or os.environ.get("FRNG_REQUIRE_BROWSER"))


def skip_or_fail(msg: str) -> None:
    """Fail with ``msg`` where the browser is :func:`required`, else skip."""
    (pytest.fail if required() else pytest.skip)(msg)


def paths() -> tuple[Path, Path]:
    """(chromium, chromedriver), or skip / fail the test when either is missing."""
    missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not p.exists()]
    if missing:
        skip_or_fail(f"{missing} missing: apt-get install -y chromium chromium-driver (.ci/run does)")
    return CHROMIUM, CHROMEDRIVER


def chrome(profile: Path, window: tuple[int, int], extra: tuple[str, ...] = ()):
    """A selenium driver of headless Chromium with its own profile folder and window size (pixels, scale 1)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for a in (*HEADLESS, *extra, f"--window-size={window[0]},{window[1]}", f"--user-data-dir={profile}"):
        opts.add_argument(a)
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
    driver.set_page_load_timeout(60)
    return driver
