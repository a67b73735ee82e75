"""Self-contained HTML: every image is embedded as a base64 data URI, the CSS
is inline, nothing is loaded from elsewhere (the file can be mailed/archived).

A report is a list of :class:`Section`; a section holds blocks (HTML
fragments) made by :func:`image`, :func:`table`, :func:`missing`,
:func:`paragraph` and :func:`gallery`.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

MISSING_CLASS = "missing"

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em auto;
max-width:1200px;color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
h3{margin-top:1.4em}
table{border-collapse:collapse;font-size:.8em;margin:.5em 0}
th,td{border:1px solid #ddd;padding:.2em .45em;text-align:right}
th{background:#f3f3f3}td.s,th.s{text-align:left}
figure{display:inline-block;margin:.4em .6em .4em 0;vertical-align:top}
figcaption{font-size:.8em;color:#555;max-width:100%}
img{max-width:100%;border:1px solid #eee}
div.missing{color:#a33;background:#fdf0f0;border:1px dashed #d99;padding:.2em .5em;display:inline-block;
font-size:.85em;margin:.3em 0}
td.missing{color:#a33;background:#fdf0f0}
.scroll{overflow-x:auto;max-width:100%}
.scroll table{margin:0}
.meta{color:#666;font-size:.85em}
nav a{margin-right:1em}
"""


@dataclass
class Section:
    """A titled part of the report (level 2 or 3 heading) with HTML blocks."""

    title: str
    blocks: list[str] = field(default_factory=list)
    level: int = 2
    anchor: str = ""

    def add(self, block: str) -> "Section":
        self.blocks.append(block)
        return self


def data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def image(png: bytes, alt: str, caption: str = "") -> str:
    """A figure with an embedded PNG and an optional caption."""
    cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return f'<figure><img src="{data_uri(png)}" alt="{html.escape(alt, quote=True)}">{cap}</figure>'


def missing(what: str) -> str:
    """The marker shown where an input does not exist (never a faked plot)."""
    return f'<div class="{MISSING_CLASS}">missing: {html.escape(what)}</div>'


def paragraph(text: str, cls: str = "") -> str:
    c = f' class="{cls}"' if cls else ""
    return f"<p{c}>{html.escape(text)}</p>"


def gallery(items: list[str]) -> str:
    return "<div>" + "".join(items) + "</div>"


def _cell(v) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)) or v is pd.NA:
        return '<td class="missing">missing</td>'
    if isinstance(v, (float, np.floating)):
        return f"<td>{float(v):.4g}</td>"
    if isinstance(v, (int, np.integer)):
        return f"<td>{int(v)}</td>"
    return f'<td class="s">{html.escape(str(v))}</td>'


def table(df: pd.DataFrame) -> str:
    """An HTML table of ``df`` (floats to 4 significant digits, missing cells
    marked as plain cells of the grid)."""
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    rows = []
    for rec in df.itertuples(index=False, name=None):
        rows.append("<tr>" + "".join(_cell(v) for v in rec) + "</tr>")
    # in a box of its own that scrolls sideways: a wide table never widens the page
    return (f'<div class="scroll"><table><thead><tr>{head}</tr></thead>'
            f"<tbody>{''.join(rows)}</tbody></table></div>")


def assemble(title: str, sections: list[Section], meta: str = "") -> str:
    """The complete HTML document (a string)."""
    nav = " ".join(f'<a href="#{html.escape(s.anchor)}">{html.escape(s.title)}</a>'
                   for s in sections if s.level == 2 and s.anchor)
    body = []
    for s in sections:
        aid = f' id="{html.escape(s.anchor)}"' if s.anchor else ""
        body.append(f"<h{s.level}{aid}>{html.escape(s.title)}</h{s.level}>")
        body.extend(s.blocks)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>"
            f"<h1>{html.escape(title)}</h1>"
            + (f'<p class="meta">{html.escape(meta)}</p>' if meta else "")
            + f"<nav>{nav}</nav>\n" + "\n".join(body) + "\n</body></html>\n")
