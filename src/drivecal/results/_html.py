"""One fit's summary as an HTML table (the Calibration's Jupyter view and the report's first table), and the
escaping and number formatting every drivecal HTML page uses."""

from __future__ import annotations

import html as _html
import math
from typing import Any, Mapping

from .._units import estimate_cells, format_value


def escape(x: Any) -> str:
    return _html.escape(str(x))


def format_number(x: Any, spec: str = ".6g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)


def summary_html(fit: Mapping[str, Any]) -> str:
    """The summary table of one fit: prior, estimate, SE, 95 % CI, relative CI, change against the prior,
    identifiable; each parameter in its engineering unit (mΩ, mH, mWb), the estimate and its interval to the
    SE's second significant digit, the prior (the motor file's datasheet value) in the same prefix."""
    rows = []
    for name, p in fit["parameters"].items():
        ok = p["identifiable"]
        ci = p["ci95"] or [None, None]
        est = p["estimate"]
        cells = estimate_cells(est if est is not None else float("nan"), p["unit"], p["se"] if ok else None,
                               tuple(ci))
        rel = 50.0 * (ci[1] - ci[0]) / abs(est) if ok and None not in ci and est else None
        prior = p.get("prior")
        change = (100.0 * (est - prior) / abs(prior)
                  if ok and est is not None and isinstance(prior, (int, float)) and prior else None)
        ident = "yes" if ok else f"NO: {p.get('reason', 'not identifiable')} (held at prior)"
        prior_cell = format_value(prior, cells.scale) if isinstance(prior, (int, float)) else "-"
        change_cell = "-" if change is None else f"{change:+.{_decimals(rel)}f}"
        rows.append(
            f'<tr class="{"yes" if ok else "no"}"><td class="l">{escape(name)}</td><td class="l">{escape(cells.unit)}'
            f"</td><td>{prior_cell}</td><td>{cells.estimate}</td><td>{cells.se}</td><td>{cells.ci[0]}</td>"
            f'<td>{cells.ci[1]}</td><td>{"-" if rel is None else format_value(rel, 1.0, rel)}</td>'
            f'<td>{change_cell}</td><td class="l">{escape(ident)}</td></tr>'
        )
    head = ("<tr><th class='l'>parameter</th><th class='l'>unit</th><th>prior [unit]</th><th>estimate [unit]</th>"
            "<th>SE [unit]</th><th>95 % CI low [unit]</th><th>95 % CI high [unit]</th>"
            "<th>relative CI half-width [%]</th><th>change against the prior [%]</th>"
            "<th class='l'>identifiable</th></tr>")
    return f'<table class="summary">{head}{"".join(rows)}</table>'


def _decimals(rel: float | None) -> int:
    """Decimals of a percentage shown beside a relative half-width ``rel`` [%]: to its second significant digit."""
    if rel is None or not math.isfinite(rel) or rel <= 0:
        return 1
    return max(0, min(6, 1 - math.floor(math.log10(rel))))
