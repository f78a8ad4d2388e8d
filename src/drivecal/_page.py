"""What drivecal's HTML pages share: the style sheet, and figures embedded as PNG ``data:`` URIs.

Plain Python and matplotlib (loaded only when a figure is drawn), no JAX: the fit's report
(``drivecal.report``) and the fleet report (``drivecal.fleet``) both use it, and the fleet report
loads nothing of the fitting stack.
"""

from __future__ import annotations

import base64

#: Resolution of the embedded figures (dots per inch); fixed for byte-identical PNGs.
FIG_DPI = 80

#: The pages' style sheet (inline: a page fetches nothing).
CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:1.5em auto;max-width:1250px;color:#222;
     padding:0 1em;line-height:1.4}
h1{margin-bottom:.1em} .stamp{color:#666;font-size:.9em;margin-top:0}
.verdict{border-left:8px solid;padding:.6em 1em;margin:.8em 0;font-size:1.15em;background:#f6f6f6}
.verdict.calibrated{border-color:#2a9d3f} .verdict.partial{border-color:#e0a100}
.verdict.mismatch,.verdict.failed{border-color:#c62828}
.verdict b{font-size:1.15em} .verdict ul{margin:.3em 0 0 0;font-size:.85em}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right} th{background:#eee}
td.l,th.l{text-align:left} tr.no td{color:#999}
figure{margin:1em 0} figure img{max-width:100%;height:auto;border:1px solid #ddd}
figcaption{color:#555;font-size:.9em}
section.fit{border-top:3px solid #444;margin-top:2em}
code{font-size:.9em}
ul.plain{font-size:1.05em} tr.failed td{color:#c62828} tr.skipped td{color:#777}
details.statistics{margin:1.2em 0;border:1px solid #ccc;padding:.4em .8em}
details.statistics summary{cursor:pointer;font-weight:bold}
"""


def figure_data_uri(fig) -> str:
    """PNG of a matplotlib figure as a ``data:`` URI; the figure is closed.

    Deterministic: fixed dpi, drawn once and cut to its content, no ``Software`` metadata.
    """
    from . import _figures

    return png_data_uri(_figures.png_bytes(fig, FIG_DPI))


def png_data_uri(png: bytes) -> str:
    """PNG bytes as a ``data:`` URI."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")
