"""A small, safe HTML builder for self-contained reports.

Every piece of text goes through :func:`text` (``html.escape`` with quotes), so a file
name or a metadata value such as ``<script>`` arrives in the page as text, never as
markup. Figures are embedded as base64 ``data:`` URIs, so the page needs no network
and no neighbouring files. Numbers go through :func:`number`: a missing or non-finite
value is shown as an em dash, never as "nan".

The builder returns :class:`Markup` (a ``str`` subclass marking HTML that is already
safe); anything else handed to it is escaped.
"""

from __future__ import annotations

import base64
import html
import math
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Markup", "badge", "details", "figure", "join", "number", "page", "paragraph",
           "section", "table", "text", "unit_text"]

MISSING = "—"


class Markup(str):
    """HTML that is safe to insert as is (built by this module)."""

    __slots__ = ()


def text(value: Any) -> Markup:
    """``value`` as escaped HTML text (Markup passes through unchanged)."""
    if isinstance(value, Markup):
        return value
    return Markup(html.escape(str(value), quote=True))


def unit_text(unit: str) -> str:
    """A unit as a reader writes it: ``um`` -> ``µm`` (also inside ``um/V``)."""
    return re.sub(r"\bum\b", "µm", unit or "")


def join(parts: Iterable[Any], sep: str = "\n") -> Markup:
    """Concatenate parts, escaping those that are not Markup."""
    return Markup(sep.join(text(p) for p in parts))


def number(value: Any, spec: str = ".4g") -> Markup:
    """A number formatted with ``spec``; None, NaN and infinities show as an em dash."""
    if value is None or isinstance(value, str):
        return text(MISSING if value is None else value)
    if isinstance(value, bool | np.bool_):
        return text("yes" if value else "no")
    try:
        x = float(value)
    except (TypeError, ValueError):
        return text(value)
    return text(format(x, spec) if math.isfinite(x) else MISSING)


def _cell(value: Any, spec: str | None = None) -> Markup:
    if isinstance(value, Markup):
        return value
    if isinstance(value, float | int | np.floating | np.integer | bool | np.bool_) \
            or value is None:
        return number(value, spec or ".4g")
    return text(value)


def table(columns: Sequence[str], rows: Iterable[Sequence[Any]], *,
          caption: str | None = None, numeric: Sequence[bool] | None = None,
          formats: Sequence[str | None] | None = None) -> Markup:
    """An HTML table; cells are escaped text, numbers (via :func:`number`) or Markup.

    Parameters
    ----------
    columns : sequence of str
        Header cells.
    rows : iterable of sequences
        One sequence per row, as long as ``columns``.
    caption : str, optional
    numeric : sequence of bool, optional
        Right-align these columns (default: columns whose first cell is a number).
    formats : sequence of str or None, optional
        Format spec of each column's numbers (None: ``.4g``).
    """
    rows = [list(r) for r in rows]
    fmts = list(formats) if formats is not None else [None] * len(columns)
    if len(fmts) != len(columns):
        raise ValueError(f"{len(fmts)} formats for {len(columns)} columns")
    for i, r in enumerate(rows):
        if len(r) != len(columns):
            raise ValueError(f"table row {i} has {len(r)} cells for {len(columns)} columns")
    if numeric is None:
        numeric = [bool(rows) and isinstance(rows[0][j], float | int | np.floating | np.integer)
                   and not isinstance(rows[0][j], bool) for j in range(len(columns))]
    cls = [' class="num"' if n else "" for n in numeric]
    head = "".join(f"<th{c}>{text(h)}</th>" for h, c in zip(columns, cls, strict=True))
    body = "\n".join("<tr>" + "".join(f"<td{c}>{_cell(v, f)}</td>"
                                      for v, c, f in zip(r, cls, fmts, strict=True)) + "</tr>"
                     for r in rows)
    cap = f"<caption>{text(caption)}</caption>" if caption else ""
    return Markup(f'<div class="scroll"><table>{cap}<thead><tr>{head}</tr></thead>\n'
                  f"<tbody>\n{body}\n</tbody></table></div>")


def figure(png: str | Path | bytes, caption: str, *, alt: str | None = None) -> Markup:
    """A PNG embedded as a ``data:`` URI, with a caption."""
    data = png if isinstance(png, bytes) else Path(png).read_bytes()
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        raise ValueError(f"{png if not isinstance(png, bytes) else 'figure'} is not a PNG")
    b64 = base64.b64encode(data).decode("ascii")
    return Markup(f'<figure><img src="data:image/png;base64,{b64}" alt="{text(alt or caption)}">'
                  f"<figcaption>{text(caption)}</figcaption></figure>")


def paragraph(*parts: Any, cls: str | None = None) -> Markup:
    """A ``<p>`` of escaped text (Markup parts are inserted as is)."""
    c = f' class="{text(cls)}"' if cls else ""
    return Markup(f"<p{c}>{join(parts, '')}</p>")


def badge(ok: bool | None, yes: str = "converged", no: str = "NOT converged",
          unknown: str = "unknown") -> Markup:
    """A coloured word: green ``yes``, red ``no``, grey ``unknown`` for None."""
    if ok is None:
        return Markup(f'<span class="badge unknown">{text(unknown)}</span>')
    return Markup(f'<span class="badge {"ok" if ok else "bad"}">{text(yes if ok else no)}'
                  "</span>")


def details(summary: str, body: Any) -> Markup:
    """A collapsed block the reader can open."""
    return Markup(f"<details><summary>{text(summary)}</summary>{text(body)}</details>")


def section(anchor: str, title: str, body: Iterable[Any]) -> Markup:
    """A ``<section>`` with an ``<h2>`` that the table of contents links to."""
    return Markup(f'<section id="{text(anchor)}"><h2>{text(title)}</h2>\n'
                  f"{join(body)}\n</section>")


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;color:#222;
 line-height:1.45;background:#fafafa}
main{max-width:1100px;margin:0 auto;padding:1rem 2rem 4rem;background:#fff}
h1{font-size:1.6rem;margin-bottom:.2rem}h2{border-bottom:2px solid #ddd;padding-bottom:.2rem;
 margin-top:2.5rem}h3{margin-top:1.6rem}
nav ol{columns:2;padding-left:1.2rem}
.scroll{overflow-x:auto;margin:.6rem 0}
table{border-collapse:collapse;font-size:.85rem}
caption{text-align:left;font-weight:600;padding:.3rem 0}
th,td{border-bottom:1px solid #e4e4e4;padding:.25rem .6rem;text-align:left;vertical-align:top}
td{max-width:28rem}th,td.num{white-space:nowrap}
th{background:#f3f3f3}td.num,th.num{text-align:right;font-variant-numeric:tabular-nums}
figure{margin:1rem 0}img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:.85rem;color:#555}
.badge{padding:.05rem .45rem;border-radius:.3rem;font-size:.8rem;font-weight:600}
.ok{background:#e3f4e6;color:#1e6b2f}.bad{background:#fbe4e1;color:#a32a1c}
.unknown{background:#eee;color:#555}
.warn{background:#fff6e0;border-left:4px solid #e0a800;padding:.5rem .8rem}
.meta{color:#555;font-size:.9rem}
details{margin:.5rem 0}summary{cursor:pointer;color:#245}
"""


def page(title: str, subtitle: Any, sections: Sequence[tuple[str, str, Markup]]) -> str:
    """A complete, self-contained HTML document.

    Parameters
    ----------
    title : str
    subtitle : str or Markup
        A line under the title (escaped unless Markup).
    sections : sequence of (anchor, heading, Markup)
        In order; a table of contents links to each.
    """
    toc = "".join(f'<li><a href="#{text(a)}">{text(h)}</a></li>' for a, h, _ in sections)
    body = "\n".join(section(a, h, [b]) for a, h, b in sections)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{text(title)}</title><style>{_CSS}</style></head>\n<body><main>"
            f"<h1>{text(title)}</h1><p class=\"meta\">{text(subtitle)}</p>"
            f"<nav><ol>{toc}</ol></nav>\n{body}\n</main></body></html>\n")
