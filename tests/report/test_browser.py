"""The HTML reports in a real browser (headless Chromium): the demo's (table and every figure render) and
a bench file's fit without a plan (the plan as run, the delay, the prior column, engineering units).

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


def test_the_report_of_a_bench_files_fit_shows_what_an_engineer_shares(tmp_path, monkeypatch):
    """``drivecal fit examples/bench.csv --motor examples/motor.toml --out DIR``: a fit without a plan file,
    as a bench writes it. The page must name what was calibrated, show the segments as run (with the sample
    rate), the computation delay and the speed's use, the prior beside each estimate in mΩ / mH / mWb, every
    check done or skipped with its reason, and the statistics behind a disclosure."""
    from drivecal.cli import main

    examples = Path(__file__).resolve().parents[2] / "examples"
    monkeypatch.chdir(tmp_path)
    shutil.copytree(examples, tmp_path / "examples")
    assert main(["fit", "examples/bench.csv", "--motor", "examples/motor.toml", "--out", "out"]) == 0
    page = (tmp_path / "out" / "report.html").resolve()
    browser = _browser()
    try:
        browser.get(page.as_uri())
        q = browser.execute_script
        title, h1 = browser.title, q("return document.querySelector('h1').innerText")
        head = q("return Array.from(document.querySelectorAll('table.summary th')).map(c => c.innerText)")
        rows = q("return Array.from(document.querySelectorAll('table.summary tr')).slice(1)"
                 ".map(r => Array.from(r.cells).map(c => c.innerText))")
        setup = dict(q("return Array.from(document.querySelectorAll('table.setup tr'))"
                       ".map(r => [r.cells[0].innerText, r.cells[1].innerText])"))
        plan = q("return Array.from(document.querySelectorAll('table.plan tr')).map(r => r.innerText)")
        checks = q("return Array.from(document.querySelectorAll('table.checks tr')).slice(1)"
                   ".map(r => Array.from(r.cells).map(c => c.innerText))")
        plain = q("return document.querySelector('ul.plain').innerText")
        closed = q("return !document.querySelector('details.statistics').open")
        shown = q("return document.querySelector('table.stats').checkVisibility()")
        images = q("return Array.from(document.images).map(i => [i.complete, i.naturalWidth])")
        errors = [e for e in browser.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
    finally:
        browser.quit()
    assert title == h1 == "Calibration of motor.toml from bench.csv"
    assert [c.split(" [")[0] for c in head[:4]] == ["parameter", "unit", "prior", "estimate"]
    assert "change against the prior [%]" in head
    table = {r[0]: r for r in rows}
    assert [table[n][1] for n in ("R", "Ld", "Lq", "lambda_m")] == ["mΩ", "mH", "mH", "mWb"]
    assert [table[n][2] for n in ("R", "Ld", "Lq", "lambda_m")] == ["450", "3.2", "5.8", "53.3"]  # motor.toml
    assert setup["sample rate"] == "20 kHz" and setup["bench file"] == "examples/bench.csv"
    assert setup["computation delay"].startswith("0 samples, as assumed")
    assert setup["measured speed used as"].startswith("an exact input")
    assert len(plan) == 1 + 3 and "locked d-step" in plan[1] and "200" in plan[1]  # header, three segments
    states = {name: state for name, state, _ in checks}
    assert states["identifiability (before fitting)"] == "done"
    assert states["noise level of the residuals"] == "done"
    assert states["specification (the motor file's tolerances)"] == "skipped"
    assert all(reason.strip() for _, state, reason in checks if state == "skipped")
    assert "R = 450.0" in plain and "mΩ" in plain and "the prior 450 mΩ" in plain
    assert closed and not shown  # the statistics wait behind the disclosure
    assert len(images) >= 5 and all(done and w > 0 for done, w in images), images
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
