"""A real headless Chromium for the tests of the web pages: Debian's chromium and its version-locked
chromedriver (`./dev test` installs both), driven with selenium. Nothing is downloaded: selenium's own
driver manager is bypassed by naming the driver's path.

A test that needs a browser and finds none fails with what to install: a browser test never skips."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from selenium import webdriver
from selenium.webdriver.chrome.service import Service

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")


class NoBrowser(RuntimeError):
    pass


@contextmanager
def chromium(width: int = 1280, height: int = 800) -> Iterator[webdriver.Chrome]:
    """A headless Chromium at the given window size (the operator's 1280x800 panel by default)."""
    for needed in (CHROMIUM, CHROMEDRIVER):
        if not needed.exists():
            raise NoBrowser(f"{needed} is missing: run 'apt-get install chromium chromium-driver' "
                            "(./dev test installs them)")
    profile = tempfile.mkdtemp(prefix="statehub-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    # The machine's network is closed: without these, Chromium's background connections are refused by
    # the dozen and it looks up Google's hosts at every start.
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", f"--user-data-dir={profile}", f"--window-size={width},{height}"):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(executable_path=str(CHROMEDRIVER)), options=options)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)
