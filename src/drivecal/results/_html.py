"""One fit's summary as an HTML table (the Calibration's Jupyter view and the report's first table), and the
escaping and number formatting every drivecal HTML page uses."""

from __future__ import annotations

import html as _html
import math
from typing import Any, Mapping


def escape(x: Any) -> str:
    return _html.escape(str(x))


def format_number(x: Any, spec: str = ".6g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)


def summary_html(fit: Mapping[str, Any]) -> str:
    """The summary table of one fit: estimate, SE, 95 % CI, relative CI, identifiable."""
    rows = []
    for name, p in fit["parameters"].items():
        ok = p["identifiable"]
        ci = p["ci95"] or [None, None]
        est = p["estimate"]
        rel = 50.0 * (ci[1] - ci[0]) / abs(est) if ok and None not in ci and est else None
        ident = "yes" if ok else f"NO: {p.get('reason', 'not identifiable')} (held at prior)"
        rows.append(
            f'<tr class="{"yes" if ok else "no"}"><td class="l">{escape(name)}</td><td class="l">{escape(p["unit"])}</td>'
            f"<td>{format_number(est)}</td><td>{format_number(p['se'], '.3g')}</td><td>{format_number(ci[0])}</td><td>{format_number(ci[1])}</td>"
            f'<td>{format_number(rel, ".3g")}</td><td class="l">{escape(ident)}</td></tr>'
        )
    head = ("<tr><th class='l'>parameter</th><th class='l'>SI unit</th><th>estimate [SI unit]</th>"
            "<th>SE [SI unit]</th><th>95 % CI low [SI unit]</th><th>95 % CI high [SI unit]</th>"
            "<th>relative CI half-width [%]</th><th class='l'>identifiable</th></tr>")
    return f'<table class="summary">{head}{"".join(rows)}</table>'
