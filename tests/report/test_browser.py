"""The demo's HTML report in a real browser (headless Chromium): table and every figure render.

Skips when no browser is installed, unless ``DRIVECAL_REQUIRE_BROWSER=1``
(as in ``.ci/run``): then a missing browser is a failure.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

CHROMIUM = ("/usr/bin/chromium", "chromium", "chromium-browser", "google-chrome")
CHROMEDRIVER = ("/usr/bin/chromedriver", "chromedriver")


def _which(candidates) -> str | None:
    for c in candidates:
        found = shutil.which(c)
        if found:
            return found
    return None


def _browser():
    """A headless Chromium driven by selenium, or skip/fail with the reason."""
    required = os.environ.get("DRIVECAL_REQUIRE_BROWSER", "") == "1"
    chromium, driver = _which(CHROMIUM), _which(CHROMEDRIVER)
    reason = None
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        reason = "selenium is not installed (pip install -e '.[dev]')"
    if reason is None and not (chromium and driver):
        reason = ("no chromium/chromedriver on PATH (Debian: apt-get install chromium chromium-driver; "
                  "`make test` does it as root)")
    if reason:
        if required:
            pytest.fail(f"DRIVECAL_REQUIRE_BROWSER=1 but {reason}")
        pytest.skip(reason)
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1280,2000", "--hide-scrollbars"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(driver), options=options)


def test_demo_report_renders_in_headless_chromium(demo_run, tmp_path):
    proc, out = demo_run
    assert proc.returncode == 0, proc.stderr
    page = Path(out / "report.html").resolve()
    browser = _browser()
    try:
        browser.get(page.as_uri())
        shot = tmp_path / "report-screenshot.png"
        assert browser.save_screenshot(str(shot))
        if os.environ.get("DRIVECAL_SCREENSHOT"):
            shutil.copyfile(shot, os.environ["DRIVECAL_SCREENSHOT"])
        images = browser.execute_script(
            "return Array.from(document.images).map(i => [i.complete, i.naturalWidth, i.naturalHeight])")
        rows = browser.execute_script("return document.querySelectorAll('table.summary tr').length")
        first_verdict = browser.execute_script("return document.querySelector('.verdict').innerText")
        errors = [e for e in browser.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
    finally:
        browser.quit()
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(images) == 12  # six figures per design, two designs
    assert all(complete and w > 0 and h > 0 for complete, w, h in images), images
    assert rows == 2 * (1 + 4)  # header + one row per parameter, two designs
    assert first_verdict.startswith("Verdict: calibrated")
    assert errors == []


def test_missing_browser_skips_or_fails_as_required(monkeypatch):
    import sys

    monkeypatch.setattr(sys.modules[__name__], "CHROMIUM", ("no-such-browser-here",))
    monkeypatch.delenv("DRIVECAL_REQUIRE_BROWSER", raising=False)
    with pytest.raises(pytest.skip.Exception, match="chromium"):
        _browser()
    monkeypatch.setenv("DRIVECAL_REQUIRE_BROWSER", "1")
    with pytest.raises(pytest.fail.Exception, match="DRIVECAL_REQUIRE_BROWSER=1"):
        _browser()
