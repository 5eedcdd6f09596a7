"""Replace one marked section of ``benchmarks/RESULTS.md`` (shared by the benchmarks)."""

from __future__ import annotations

from pathlib import Path

from bayeshyst.files import atomic_path

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"

__all__ = ["RESULTS", "write_section"]


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
