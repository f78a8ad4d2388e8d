"""The fleet report of a line with planted outliers and a slow planted drift, in a real browser (headless Chromium).

The batch table is built without fits (tests/helpers/fleet_table.py): 600 motors SN1..SN600, rows in random
order, Lq drifting by ±2.5 spreads along the serials, five planted faults far outside the
population. Read back from the rendered page: the drift is visible (Lq's rolling median crosses
the set fraction of the band, the parameters without drift stay below it), every planted fault is marked
at the edge of its axes with its value, the pass/fail counts come first, and every figure loads. A
screenshot is written under tmp_path (and to ``$DRIVECAL_FLEET_SCREENSHOT`` when set).

Skips when no browser is installed, unless ``DRIVECAL_REQUIRE_BROWSER=1`` (as in ``.ci/run``).
"""

from __future__ import annotations

import json
import os
import shutil

import numpy as np

from drivecal.fleet import render_fleet_html
from helpers.fleet_table import DRIFTING, PLANTED, nominal, planted_table, tolerances
from test_browser import _browser


def test_fleet_report_shows_the_drift_and_marks_the_outliers_in_headless_chromium(tmp_path):
    table = planted_table(600, seed=3, shuffle=True)  # rows in random order: only the serial orders the line
    page = tmp_path / "fleet.html"
    page.write_text(render_fleet_html(table, "planted.parquet", nominal=nominal(), tolerances=tolerances()),
                    encoding="utf-8")
    browser = _browser()
    try:
        browser.get(page.resolve().as_uri())
        shot = tmp_path / "fleet-report-screenshot.png"
        height = browser.execute_script("return document.documentElement.scrollHeight")
        browser.set_window_size(1280, height + 200)  # the whole page in one picture
        assert browser.save_screenshot(str(shot))
        if os.environ.get("DRIVECAL_FLEET_SCREENSHOT"):
            shutil.copyfile(shot, os.environ["DRIVECAL_FLEET_SCREENSHOT"])
        data = json.loads(browser.execute_script("return document.getElementById('fleet-data').textContent"))
        images = browser.execute_script(
            "return Array.from(document.images).map(i => [i.complete, i.naturalWidth, i.naturalHeight])")
        headings = browser.execute_script("return Array.from(document.querySelectorAll('h2')).map(h => h.innerText)")
        spec_rows = browser.execute_script(
            "return Array.from(document.querySelectorAll('#spec-counts tr')).slice(1)"
            ".map(r => [r.cells[0].innerText, Number(r.cells[1].innerText)])")
        marked = browser.execute_script(
            "return Array.from(document.querySelectorAll('ul.beyond li')).map(li => "
            "[li.closest('section').dataset.param, li.dataset.serial, Number(li.dataset.value), li.innerText])")
        drift_cells = browser.execute_script(
            "return Array.from(document.querySelectorAll('#parameters td.drift'))"
            ".map(td => td.closest('tr').dataset.param)")
        checks = browser.execute_script(
            "return Array.from(document.querySelectorAll('#checks tr[data-check]')).map(r => r.dataset.check)")
        errors = [e for e in browser.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
    finally:
        browser.quit()
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert errors == []
    assert len(images) == 4 and all(ok and w > 300 and h > 100 for ok, w, h in images), images

    # Pass/fail first, as counts.
    assert headings[0] == "Pass/fail against the specification"
    assert dict(spec_rows) == table["spec"].value_counts().reindex(dict(spec_rows)).fillna(0).astype(int).to_dict()
    assert dict(spec_rows)["fail"] == len(PLANTED)
    assert checks == ["spec", "outlier", "mismatch"]

    # The drift: the rolling median of the drifting parameter crosses the set fraction of the band; the others' do not.
    for name, p in data["parameters"].items():
        fraction = p["drift_threshold"]
        assert fraction == max(data["drift_fraction"], 5 * p["drift_noise"])
        assert len(p["band"]["median"]) == (table[name].notna()).sum()  # every motor's point (no thinning here)
        edge = p["window"] // 2  # the drift is judged over full windows
        median, low, high = (np.array(p["band"][k], dtype=float)[edge:-edge] for k in ("median", "low", "high"))
        half = np.nanmedian(high - median)
        crossing = np.nanmax(np.abs(median - p["median"])) / half
        assert np.isclose(crossing, p["drift"], rtol=0.05), (name, crossing, p["drift"])
        if name == DRIFTING:
            assert crossing > fraction and p["drift_visible"], (name, crossing)
            # and it runs along the line: low at the first serials, high at the last
            assert median[0] < p["median"] - fraction * half < p["median"] + fraction * half < median[-1]
        else:
            assert crossing < fraction and not p["drift_visible"], (name, crossing)
    assert drift_cells == [DRIFTING]

    # The outliers: each planted fault is beyond its axes, marked at the edge with its value, and listed.
    want = {(name, f"SN{i}") for i, factors in PLANTED.items() for name in factors}
    assert {(param, serial) for param, serial, _, _ in marked} == want
    by_key = {(param, serial): (value, text) for param, serial, value, text in marked}
    rows = table.set_index("serial")
    for name, serial in want:
        value, text = by_key[(name, serial)]
        assert value == rows.loc[serial, name]
        view = data["parameters"][name]["view"]
        assert not view[0] <= value <= view[1]
        shown = f"{value * data['parameters'][name]['factor']:.5g}"
        assert shown in text and data["parameters"][name]["unit"] in text
    # ...and the axes hold the population and the limits, not the outliers: no wider than the population's
    # median ± (z + 1) robust SD and the limits together, a fraction of the range the outliers would need.
    limits = tolerances()
    for name, p in data["parameters"].items():
        marks = [x for x in (*limits[name], p["nominal"]) if x is not None]
        lo = min(p["median"] - (data["outlier_z"] + 1) * p["robust_sd"], *marks)
        hi = max(p["median"] + (data["outlier_z"] + 1) * p["robust_sd"], *marks)
        pad = 0.06 * (hi - lo)
        assert lo - pad <= p["view"][0] and p["view"][1] <= hi + pad, name
        if name == "R":  # faults at +40..50 %, far beyond the population and the ±5 % limits
            values = rows[name].dropna()
            assert p["view"][1] - p["view"][0] < 0.35 * (values.max() - values.min())
