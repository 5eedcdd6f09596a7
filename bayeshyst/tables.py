"""Result records in a notebook: one DataFrame per record, and HTML made from it.

Every result record has ``to_dict`` (JSON) and ``to_dataframe`` (a table of the same
numbers, one row per parameter, model, frequency or step). :class:`TableRecord` gives a
record ``_repr_html_`` from those two and its ``__str__``: Jupyter shows the record's
first line as a title and its table, nothing computed twice. :func:`flat_rows` turns the
records' dicts into rows: nested dicts become ``a.b`` columns, a pair such as a band
``[lo, hi]`` becomes ``<name>_lo``/``<name>_hi``.
"""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["TableRecord", "flat_rows", "frame"]

#: longest table shown inline in a notebook (the rest is in ``to_dataframe()``)
MAX_HTML_ROWS = 60


def _flat(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flat(v, f"{key}."))
        elif isinstance(v, list | tuple) and len(v) == 2 and all(
                isinstance(x, int | float) and not isinstance(x, bool) for x in v):
            out[f"{key}_lo"], out[f"{key}_hi"] = v
        elif isinstance(v, list | tuple):
            out[key] = "; ".join(str(x) for x in v)
        else:
            out[key] = v
    return out


def flat_rows(rows: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Dicts flattened into table rows (see the module docstring)."""
    return [_flat(r) for r in rows]


def frame(rows: Iterable[Mapping[str, Any]], *, drop: tuple[str, ...] = ()) -> Any:
    """A pandas DataFrame of flattened ``rows`` without the keys in ``drop``."""
    import pandas as pd

    return pd.DataFrame([{k: v for k, v in r.items() if k not in drop}
                         for r in flat_rows(rows)])


def _number(x: Any) -> str:
    if isinstance(x, float):
        return "—" if not math.isfinite(x) else f"{x:.4g}"
    return html.escape(str(x))


class TableRecord:
    """Mixin for result records: ``_repr_html_`` from ``__str__`` and ``to_dataframe``."""

    def to_dataframe(self) -> Any:  # pragma: no cover - every record defines its own
        """The record's numbers as a pandas DataFrame."""
        raise NotImplementedError

    def _repr_html_(self) -> str:
        lines = str(self).splitlines()
        title = html.escape(lines[0]) if lines else type(self).__name__
        table = self.to_dataframe()
        shown = table.head(MAX_HTML_ROWS)
        body = shown.to_html(index=False, na_rep="—", float_format=_number, escape=True,
                             border=0)
        more = (f"<p>… {len(table) - len(shown)} more rows in <code>to_dataframe()</code>"
                f"</p>" if len(table) > len(shown) else "")
        warn = "".join(f"<p style='color:#a33'>{html.escape(w)}</p>" for w in lines[1:]
                       if w.startswith("warning:"))
        return f"<div><p><b>{title}</b></p>{body}{more}{warn}</div>"
