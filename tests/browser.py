"""Headless Chromium for the tests that look at pages in a real browser (tests/app/test_view.py, tests/test_docs.py)."""
from __future__ import annotations

import pytest


def headless_chromium(width: int = 1200, height: int = 800):
    """A headless Chromium driven by selenium (Debian's chromium and chromium-driver; WebGL through SwiftShader),
    or a pytest skip naming what is missing. The caller quits it."""
    import shutil
    chromium, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if not chromium or not driver:
        pytest.skip("Debian's chromium and chromium-driver are not installed (./dev.sh installs them as root)")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        pytest.skip("selenium is not installed (the test extras: pip install -e '.[test]')")
    opts = Options()
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-angle=swiftshader",
              "--enable-unsafe-swiftshader", f"--window-size={width},{height}"):
        opts.add_argument(a)
    opts.binary_location = chromium
    return webdriver.Chrome(service=Service(driver), options=opts)
