"""What the benchmarks share: a median timer and the writer of one marked section of
``benchmarks/RESULTS.md``."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bayeshyst.files import atomic_path

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"

__all__ = ["RESULTS", "median_time", "write_section"]


def median_time(fn: Callable[[], Any], repeats: int = 3) -> tuple[float, Any]:
    """Median wall time (s) of ``repeats`` calls of ``fn`` and the last call's result."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def write_section(key: str, heading: str, text: str, path: Path = RESULTS) -> None:
    """Put ``text`` between ``<!-- key:begin -->`` and ``<!-- key:end -->`` markers.

    The section is appended under ``heading`` the first time; later runs replace only
    what lies between the markers, so hand-written notes elsewhere survive.
    """
    begin, end = f"<!-- {key}:begin -->", f"<!-- {key}:end -->"
    block = f"{begin}\n{text}\n{end}"
    old = path.read_text() if path.exists() else "# Benchmark results\n"
    if begin in old:
        new = old[: old.index(begin)] + block + old[old.index(end) + len(end):]
    else:
        new = old.rstrip() + f"\n\n## {heading}\n\n{block}\n"
    with atomic_path(path) as tmp:
        tmp.write_text(new)
